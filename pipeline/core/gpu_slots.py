"""Several GPUs shared by a workflow's jobs: each CUDA job takes one that no other job holds.

Snakemake counts GPUs (`--resources gpu=N`) but does not say which one a job gets, so without this every job
would open cuda:0. With `gpus: N` (N > 1) in the workflow config the workflow exports LEARNED_CLOTH_GPUS=N; a
stage about to touch CUDA (pipeline.core.cli.check_device) then locks the first free GPU's lock file and sees
only that GPU (CUDA_VISIBLE_DEVICES), as cuda:0. The lock is an flock on an open file: the kernel releases it when
the process ends, a crash or a kill included, so no slot is ever left taken. Where CUDA_VISIBLE_DEVICES already
lists GPUs (a scheduler's allocation) the slots are the first N of those.

With `jobs_per_gpu: k` (LEARNED_CLOTH_JOBS_PER_GPU, and `--resources gpu=N*k`) each GPU has k slots, so k jobs
share it: a job of small batches leaves a GPU mostly idle (launches, its Python and its start-up), and several of
them overlap there. Jobs take every GPU's first slot before any GPU's second, so they spread before they stack.
The ranks of one job (torchrun's, `training.ranks`) never share a GPU, which NCCL refuses: each rank notes its GPU
in a small file of the job's run (TORCHELASTIC_RUN_ID) in the locks' folder, and its siblings pass that GPU by.

A job may take a GPU whole (`claim_gpu(whole=True)`: every slot of one GPU, none of them held): the ranks of a
data-parallel training, whose every step waits at the all-reduce for its slowest rank, and a stage that times
things against each other (the trade-off's table), whose times would include a neighbour's kernels. Its rule asks
Snakemake for jobs_per_gpu slots a GPU so that the counts agree.
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import sys
import tempfile
import time
from pathlib import Path

from pipeline.core.errors import PipelineError

GPUS_VARIABLE = "LEARNED_CLOTH_GPUS"
JOBS_PER_GPU_VARIABLE = "LEARNED_CLOTH_JOBS_PER_GPU"
LOCKS_VARIABLE = "LEARNED_CLOTH_GPU_LOCKS"    # the lock files' folder (default: one per user under the temp dir)
RUN_VARIABLE = "TORCHELASTIC_RUN_ID"         # torchrun's id of one launch: the ranks of one job share it

_held: tuple[str, tuple[int, ...]] | None = None    # (the GPU's id, its locked slots' descriptors): the process's life
_sharing = 1                                 # the jobs the held GPU takes at once (jobs_per_gpu), 1 without a slot


def claim_gpu(poll_seconds: float = 0.5, whole: bool = False) -> str | None:
    """Take a free GPU of LEARNED_CLOTH_GPUS and make it the only one CUDA shows this process; its id, or None
    where the variable is absent or 1. Waits while every slot is held (more CUDA jobs than `--resources gpu`).
    `whole`: every slot of one GPU (waits until some GPU has all of them free)."""
    global _held, _sharing
    if _held is not None:
        return _held[0]
    ids = _slot_ids(os.environ.get(GPUS_VARIABLE), os.environ.get("CUDA_VISIBLE_DEVICES"))
    if ids is None:
        return None
    per_gpu = _jobs_per_gpu(os.environ.get(JOBS_PER_GPU_VARIABLE))
    slots = [(gpu, k) for k in range(per_gpu) for gpu in ids]
    folder = Path(os.environ.get(LOCKS_VARIABLE) or Path(tempfile.gettempdir()) / f"learned-cloth-gpus-{os.getuid()}")
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    run = _run_of_ranks(os.environ)
    announced = False
    while True:
        with _siblings_lock(folder, run) as siblings:
            claimed = (_claim_whole_gpu(folder, ids, per_gpu, siblings.read()) if whole
                       else _claim_free_slot(folder, slots, siblings.read()))
            if claimed is not None:
                siblings.add(claimed[0])
        if claimed is not None:
            gpu, k, fds = claimed
            _held, _sharing = (gpu, fds), 1 if whole else per_gpu
            os.environ["CUDA_VISIBLE_DEVICES"] = gpu
            os.environ[GPUS_VARIABLE] = "1"     # what this process starts shares its GPU, as torch's own workers do
            shared = (f", all {per_gpu} of its slots" if whole else f", slot {k + 1} of its {per_gpu}") \
                if per_gpu > 1 else ""
            print(f"GPU {gpu} (a free one of {len(ids)}: {GPUS_VARIABLE}{shared}) is this job's cuda:0",
                  file=sys.stderr)
            return gpu
        if not announced:
            print("waiting for a GPU with all its slots free: other jobs hold a slot of each (or this job's other "
                  "ranks hold it)" if whole else f"all {len(slots)} GPU slots held by other jobs (or on this job's "
                  f"other ranks' GPUs): waiting for one", file=sys.stderr)
            announced = True
        time.sleep(poll_seconds)


def _lock_slot(folder: Path, gpu: str, k: int) -> int | None:
    """Slot k of `gpu` locked (the lock's descriptor), or None if another process holds it."""
    fd = os.open(folder / (f"gpu-{gpu}.lock" if k == 0 else f"gpu-{gpu}-slot{k}.lock"), os.O_RDWR | os.O_CREAT,
                 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def _claim_free_slot(folder: Path, slots: list[tuple[str, int]],
                     passed_by: set[str]) -> tuple[str, int, tuple[int, ...]] | None:
    """The first free slot (gpu, k) on a GPU not in `passed_by`, locked: (gpu, k, (the lock's descriptor,))."""
    for gpu, k in slots:
        fd = None if gpu in passed_by else _lock_slot(folder, gpu, k)
        if fd is not None:
            return gpu, k, (fd,)
    return None


def _claim_whole_gpu(folder: Path, ids: list[str], per_gpu: int,
                     passed_by: set[str]) -> tuple[str, int, tuple[int, ...]] | None:
    """The first GPU not in `passed_by` whose every slot is free, all of them locked: (gpu, 0, descriptors). A
    GPU with a slot held gives back the ones just taken (a half-claimed GPU would block its other jobs)."""
    for gpu in ids:
        if gpu in passed_by:
            continue
        fds = []
        for k in range(per_gpu):
            fd = _lock_slot(folder, gpu, k)
            if fd is None:
                break
            fds.append(fd)
        if len(fds) == per_gpu:
            return gpu, 0, tuple(fds)
        for fd in fds:
            os.close(fd)
    return None


def _run_of_ranks(environ) -> str | None:
    """A name for this process's job among its ranks' (a digest of torchrun's run id: a file name whatever the
    id holds), or None for a job of one process."""
    run, world = environ.get(RUN_VARIABLE), environ.get("WORLD_SIZE", "1").strip()
    if run is None or world in ("", "0", "1"):
        return None
    return hashlib.sha256(run.encode()).hexdigest()[:16]


class _Siblings:
    """The GPUs a job's other ranks took (the run's file in the locks' folder); nothing without ranks."""

    def __init__(self, path: Path | None):
        self.path = path

    def read(self) -> set[str]:
        return set(self.path.read_text().split()) if self.path is not None and self.path.exists() else set()

    def add(self, gpu: str) -> None:
        if self.path is not None:
            with open(self.path, "a") as f:
                f.write(f"{gpu}\n")


@contextlib.contextmanager
def _siblings_lock(folder: Path, run: str | None):
    """The job's ranks claim one at a time (under the run's lock), each seeing the GPUs the others took."""
    if run is None:
        yield _Siblings(None)
        return
    fd = os.open(folder / f"ranks-{run}.lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield _Siblings(folder / f"ranks-{run}.gpus")
    finally:
        os.close(fd)      # closing the descriptor releases the lock


def jobs_sharing_the_gpu() -> int:
    """How many jobs the GPU this process claimed takes at once (`jobs_per_gpu`; 1 without a claimed slot or with
    the whole GPU): a time measured here with more than 1 may include the other jobs' kernels."""
    return _sharing


def _jobs_per_gpu(text: str | None) -> int:
    """The jobs one GPU takes at once (absent: 1)."""
    if text is None or text.strip() == "":
        return 1
    if not text.strip().isdigit() or not 1 <= int(text) <= 64:
        raise PipelineError(f"{JOBS_PER_GPU_VARIABLE}={text!r}: give a whole number of jobs a GPU, 1 to 64")
    return int(text)


def _slot_ids(count_text: str | None, visible: str | None) -> list[str] | None:
    """The GPU ids to share, or None when there is nothing to choose (no count, a count of 1)."""
    if count_text is None or count_text.strip() in ("", "1"):
        return None
    if not count_text.strip().isdigit() or int(count_text) < 1:
        raise PipelineError(f"{GPUS_VARIABLE}={count_text!r}: give a whole number of GPUs, at least 1")
    count = int(count_text)
    ids = [gpu.strip() for gpu in visible.split(",") if gpu.strip()] if visible is not None else \
        [str(gpu) for gpu in range(count)]
    if len(ids) < count:
        raise PipelineError(f"{GPUS_VARIABLE}={count} but CUDA_VISIBLE_DEVICES={visible!r} lists {len(ids)} GPU(s)")
    return ids[:count]
