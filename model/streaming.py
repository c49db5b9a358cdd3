"""Training on a dataset larger than RAM and device memory: the frames stay on disk and a background thread reads
what each batch needs, so that reading is off the step's critical path.

The step itself does not change: it still gathers a batch from a `Frames` on the device by frame ids. A
`StreamedFrames` is a `Frames` whose store is a staging area of one batch (its frames' x_low in rows [0, C), their
previous frames' in [C, 2C), the ones before those in [2C, 3C), so that its `previous` table is fixed), refilled
before every step; its `feed` turns an epoch's order of frame ids into the staging area's ids [0, b). Same ids,
same rows, same arithmetic: on the CPU a streamed training is the resident one bit for bit (and a CUDA graph,
which replays the same addresses, reads each batch's frames from the refilled staging area).

The loader thread reads the frames of a window of the order at once (the sampler's blocks make them runs of
consecutive frames: one read each, model.sampler), gathers each batch into pinned host memory and queues it; the
main thread copies it to the device with non_blocking copies, queued on the stream behind the previous step. A
read error (damaged data) reaches the main thread as the exception the reader raised.
"""
from __future__ import annotations

import ctypes
import dataclasses
import queue
import threading
from typing import Callable, Iterator

import numpy as np
import torch

from model.features import FrameStore, Subdivider
from model.training import Frames

FrameRead = Callable[[int, int], tuple[np.ndarray, np.ndarray]]   # frames [first, stop) -> x_low, targets (float32)
_DONE = object()
# glibc's malloc_trim (None elsewhere): see release_freed_memory.
_MALLOC_TRIM = getattr(ctypes.CDLL(None), "malloc_trim", None)


def release_freed_memory() -> None:
    """Hand the free pages inside the C heap back to the system (glibc's malloc_trim; elsewhere nothing). The
    loader's windows (arrays of a few MB, allocated in its thread) and the step's tensors (in the main thread) are
    freed in an order that leaves the heap fragmented, and glibc returns only its free top: without this a CPU
    evaluation streaming 20k frames of 1,089 vertices grew from 0.4 to 1.0 GB resident (its frames: 0.27 GB),
    with it staying at ~0.5 GB (bench/evaluate_stream.py, docs/performance.md). Once per window: a few ms."""
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


@dataclasses.dataclass(frozen=True)
class FrameSource:
    """A dataset's frames on the host: x_low and targets read on request, the small per-frame context held."""

    read: FrameRead
    n_frames: int
    previous: np.ndarray         # (F,) int64: model.features.previous_frames
    capsule_a: np.ndarray        # (F, P, 3) float32
    capsule_b: np.ndarray
    radius_a: np.ndarray         # (P,)
    radius_b: np.ndarray
    gravity: np.ndarray          # (F, 3)
    frame_time: float

    def frames(self, ids: np.ndarray) -> dict[str, np.ndarray]:
        """x_low of the frames `ids`, of their previous frames and of the frames before those (3, B, V_low, 3),
        their targets (B, V, 3) and context: one read per run of consecutive frames needed."""
        previous = self.previous[ids]
        rows = np.stack([ids, previous, self.previous[previous]])
        needed = np.unique(np.concatenate([rows.ravel(), ids]))
        runs = np.split(needed, np.flatnonzero(np.diff(needed) != 1) + 1)
        reads = [self.read(int(run[0]), int(run[-1]) + 1) for run in runs]
        low, targets = (np.concatenate([r[k] for r in reads]) for k in (0, 1))
        return {"low": low[np.searchsorted(needed, rows)], "targets": targets[np.searchsorted(needed, ids)],
                "capsule_a": self.capsule_a[ids], "capsule_b": self.capsule_b[ids], "gravity": self.gravity[ids]}

    def store(self, ids: np.ndarray, device: torch.device, subdivide: Subdivider) -> tuple[FrameStore, torch.Tensor]:
        """The frames `ids` alone as a resident store on `device`, laid out as a staging area, and their targets."""
        arrays = {k: torch.as_tensor(v, device=device) for k, v in self.frames(ids).items()}
        b = len(ids)
        previous = torch.cat([torch.arange(b, 3 * b), torch.arange(2 * b, 3 * b)]).to(device)
        store = FrameStore(arrays["low"].reshape(3 * b, *arrays["low"].shape[2:]), subdivide, previous,
                           arrays["capsule_a"], arrays["capsule_b"], torch.as_tensor(self.radius_a, device=device),
                           torch.as_tensor(self.radius_b, device=device), arrays["gravity"], self.frame_time)
        return store, arrays["targets"]


class DiskStore:
    """Every frame of a source as `FrameStore.batch` and the targets answer for ids, read when asked (for the
    normalisation's statistics, model.feature_regressor: a few hundred frames, once)."""

    def __init__(self, source: FrameSource, device: torch.device, subdivide: Subdivider):
        self.source, self.device, self.subdivide = source, device, subdivide

    def __len__(self) -> int:
        return self.source.n_frames

    def batch(self, ids: torch.Tensor):
        store, _ = self.source.store(ids.cpu().numpy(), self.device, self.subdivide)
        return store.batch(torch.arange(len(ids), device=self.device))

    def __getitem__(self, ids: torch.Tensor) -> torch.Tensor:      # the targets of the frames `ids`
        return self.source.store(ids.cpu().numpy(), self.device, self.subdivide)[1]


@dataclasses.dataclass(frozen=True, eq=False)
class StreamedFrames(Frames):
    """Frames read from a `FrameSource` a batch at a time into a staging area on the device (module docstring)."""

    source: FrameSource | None = None
    window: int = 4096           # frames of the order whose reads are grouped (training.sample_buffer)

    @classmethod
    def create(cls, source: FrameSource, subdivide: Subdivider, faces: torch.Tensor, n_vertices: int,
               capacity: int, device: torch.device, window: int = 4096) -> StreamedFrames:
        """Staging for batches of up to `capacity` frames of meshes of `n_vertices` (high-res) on `device`."""
        ids = np.zeros(capacity, np.int64)
        store, _ = source.store(ids, device, subdivide)
        targets = torch.zeros(capacity, n_vertices, 3, device=device)
        return cls(store, targets, faces, source, window)

    @property
    def capacity(self) -> int:
        return len(self.targets)

    def all_frames(self) -> tuple[DiskStore, DiskStore]:
        disk = DiskStore(self.source, self.targets.device, self.store.subdivide)
        return disk, disk

    def feed(self, order: torch.Tensor, batch_size: int) -> Iterator[torch.Tensor]:
        if batch_size > self.capacity:
            raise ValueError(f"batches of {batch_size} frames in a staging area of {self.capacity}")
        device = self.targets.device
        local = torch.arange(batch_size, device=device)
        loaded: queue.Queue = queue.Queue(maxsize=max(2, self.window // batch_size + 1))
        stop = threading.Event()
        thread = threading.Thread(target=self._load, args=(order.cpu().numpy(), batch_size, loaded, stop),
                                  daemon=True)
        thread.start()
        try:
            while (staged := loaded.get()) is not _DONE:
                if isinstance(staged, BaseException):
                    raise staged
                self._stage(staged)
                yield local[:len(staged["targets"])]
        finally:
            stop.set()
            while thread.is_alive():         # unblock a loader waiting on a full queue
                try:
                    loaded.get(timeout=0.05)
                except queue.Empty:
                    pass
            thread.join()

    def _load(self, order: np.ndarray, batch_size: int, loaded: queue.Queue, stop: threading.Event) -> None:
        """Loader thread: per window of the order (a whole number of batches), one read per run of frames, then
        each batch gathered into pinned memory (on CUDA) and queued."""
        pin = self.targets.is_cuda
        window = max(1, self.window // batch_size) * batch_size
        try:
            for start in range(0, len(order), window):
                release_freed_memory()
                part = order[start:start + window]
                arrays = self.source.frames(part)         # row k: the frame at position k of `part`
                for first in range(0, len(part), batch_size):
                    rows = slice(first, first + batch_size)
                    batch = {k: torch.from_numpy(np.ascontiguousarray(v[:, rows] if k == "low" else v[rows]))
                             for k, v in arrays.items()}
                    if pin:
                        batch = {k: v.pin_memory() for k, v in batch.items()}
                    if stop.is_set():
                        return
                    loaded.put(batch)
        except BaseException as err:     # raised again in the main thread, where the step waits for it
            loaded.put(err)
            return
        loaded.put(_DONE)

    def _stage(self, batch: dict[str, torch.Tensor]) -> None:
        """Copy a loaded batch into the staging area (non_blocking: queued behind the previous step)."""
        b, store = len(batch["targets"]), self.store
        store.low.view(3, self.capacity, *store.low.shape[1:])[:, :b].copy_(batch["low"], non_blocking=True)
        for name, staging in (("targets", self.targets), ("capsule_a", store.capsule_a),
                              ("capsule_b", store.capsule_b), ("gravity", store.gravity)):
            staging[:b].copy_(batch[name], non_blocking=True)
