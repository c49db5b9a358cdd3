"""dataset.h5, written by the `dataset` stage: one learning problem of paper Table 2 (cloth upsampling; or a
decoder task: pose to cloth, PCA details recovery) over the frames of a scene's sequences, which sequence each
frame comes from, the mannequin of each frame (garment scenes), and the train/test/held-out split
(docs/artifacts.md, section "dataset.h5"); read back by `train` and `evaluate`.

Every task stores per frame the `target` displacement from its predictor. The upsampling's input and predictor
are S x_low, which is not stored: the low-res run `low/positions` and the subdivision matrix S (`subdivision/`)
are, and S x_low is computed where it is used (model.features.FrameStore; `LearningData.predictor`): 15 times
smaller at the paper's pants. A decoder task stores its `input` (one vector per frame) and its `predictor`
positions. A file without attr `task` is an upsampling dataset. Root attr `format` says which layout a file has;
one of another (an older one, which stored S x_low as `input`) is refused with one error.

The per-frame arrays are chunked by a few frames (`chunk_frames`: about a MiB of targets a chunk), so that a run
of consecutive frames is one contiguous read: training streams datasets larger than memory that way
(`FrameReader`, model.streaming). The writer takes the sequences one at a time, so the stage holds a few
sequences in memory (those its --threads prepare ahead), not the whole dataset, and digests the frames as they
pass (attr `frames_digest`, on a thread beside the writing): a dataset's fingerprint is known without reading
every frame back.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Iterable, Mapping

import h5py
import numpy as np
import scipy.sparse as sp

from model.features import previous_frames
from pipeline.artifacts.scene import CAPSULE_RADIUS_A, CAPSULE_RADIUS_B, MannequinFrames, read_torso_transforms
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import FLOAT32_MAX, SOURCE_MESH, atomic_h5, open_artifact, read, read_csr, read_indices, write_csr

STAGE = "dataset"
FORMAT, DATASET_FORMAT = "format", "trimesh-cnn/dataset-2"     # root attr; 1 (no attr) stored S x_low as `input`
INPUT, TARGET, PREDICTOR = "input", "target", "predictor"       # a decoder task's; the upsampling's target only
SUBDIVISION = "subdivision"      # the upsampling's S (V_high, V_low) as CSR arrays: S x_low is the predictor
FRAMES_DIGEST, CHUNK_FRAMES = "frames_digest", "chunk_frames"   # root attrs
CHUNK_BYTES = 2 ** 20            # of targets per chunk of frames
TASK, UPSAMPLING = "task", "upsampling"          # root attr naming the task; absent: the upsampling
# PCA details recovery: the basis the inputs are coefficients of (pipeline/tasks/pca.py).
PCA_MEAN, PCA_COMPONENTS, PCA_SINGULAR_VALUES = "pca/mean", "pca/components", "pca/singular_values"
FACES, REST_VERTICES, LOW_POSITIONS, LOW_FACES = "faces", "rest_vertices", "low/positions", "low/faces"
SEQUENCE, SEQUENCE_FRAME = "sequence", "sequence_frame"
SEQUENCE_NAMES, SEQUENCE_ROLES, SEQUENCE_CLIPS = "sequences/names", "sequences/role", "sequences/clips"
# A motion library's windows, per sequence ("" where it plays none): scenes.library.LibraryWindow.describe.
WINDOW_FIELDS = {"file": "sequences/library_file", "subject": "sequences/subject", "category": "sequences/category"}
SEQUENCE_SPAN = "sequences/library_span"
DROPPED_NAMES, DROPPED_REASONS = "dropped/names", "dropped/reasons"
SPLIT, SPLIT_TRAIN, SPLIT_TEST, SPLIT_HELD_OUT = "split", "split/train", "split/test", "split/held_out"
SPLIT_NAMES_TRAINED = ("train", "held_out")   # the splits a model may be trained on (train's --train-on)
SPLIT_GUARD = "split/guard"     # test split `windows`: the frames too near a test frame to train on
TEST_SPLIT, TEST_WINDOW, GUARD = "test_split", "test_window", "guard"    # root attrs: how the test frames were drawn
RANDOM, WINDOWS = "random", "windows"        # the test splits (settings `dataset.test_split`)
# What the cloth of each frame moves in, in the dataset's reference frame: the inputs of body- and
# gravity-relative network features (model.features).
CONTEXT_GRAVITY, CONTEXT_CAPSULE_A, CONTEXT_CAPSULE_B = "context/gravity", "context/capsule_a", "context/capsule_b"
SPLIT_MEANING = ("train: frames trained on; test: a seeded random share of the training sequences' frames; "
                 "held_out: every frame of the held-out sequences (unseen motion, the clips named in attr "
                 "held_out_clips; may be empty)")
WINDOWS_SPLIT_MEANING = ("train: frames trained on; test: seeded contiguous blocks of the training sequences' "
                         "frames (root attrs test_window, guard); guard: the training sequences' frames within "
                         "`guard` seconds of a test frame, in their run or in their library file's motion, in no "
                         "split; held_out: every frame of the held-out sequences (unseen motion, the clips named in "
                         "attr held_out_clips; may be empty)")


@dataclasses.dataclass(frozen=True)
class SplitRule:
    """How the test frames were drawn from the training sequences: `random` frames (the paper's way), or
    `windows`: contiguous blocks of at most `window` seconds, no frame trained on within `guard` seconds of one."""

    kind: str = RANDOM
    window: float = 0.0          # windows: seconds of the longest block
    guard: float = 0.0           # windows: seconds


@dataclasses.dataclass(frozen=True)
class Split:
    """Frame ids of each split."""

    train: np.ndarray
    test: np.ndarray
    held_out: np.ndarray         # every frame of the held-out sequences (may be empty)
    held_out_clips: tuple[str, ...]
    guard: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))   # windows: in no split
    test_split: SplitRule = SplitRule()


def count_test_frames(n_frames: int, test_fraction: float) -> int:
    """How many of `n_frames` training frames are test: the share rounded, at least one, and one short of all."""
    if n_frames < 2:
        raise PipelineError(f"a train/test split needs at least 2 frames of training sequences, got {n_frames}")
    return min(max(1, int(round(test_fraction * n_frames))), n_frames - 1)


def split_frames(n_frames: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split (the paper's; every task's dataset draws it so): sorted train and test frame ids, at
    least one frame in each."""
    n_test = count_test_frames(n_frames, test_fraction)
    order = np.random.default_rng(seed).permutation(n_frames)
    return np.sort(order[n_test:]), np.sort(order[:n_test])


@dataclasses.dataclass(frozen=True)
class PcaBasis:
    """A PCA of high-res positions (reference frame): x ≈ mean + sum_k c_k components[k], components orthonormal
    as (V * 3)-vectors."""

    mean: np.ndarray               # (V, 3)
    components: np.ndarray         # (K, V, 3)
    singular_values: np.ndarray    # (K,) of the centred frames it was fitted to
    explained: float               # share of those frames' variance the K components hold
    fitted_frames: int             # training frames it was fitted to


@dataclasses.dataclass(frozen=True)
class TaskLayout:
    """What a decoder task's dataset holds besides the frames (None in DatasetLayout: the upsampling)."""

    name: str                      # pose or pca (pipeline/tasks)
    input_size: int                # scalars of the input vector per frame
    problem: str                   # attr `problem`: what is learned, in words
    input_meaning: str
    predictor_meaning: str
    pca: PcaBasis | None = None
    # root attrs of the task's own (the hand: what its simulation cost a frame; read back by read_task_attrs)
    attrs: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class DatasetLayout:
    """What the dataset holds, known before any sequence's frames are read: meshes, where each frame comes from,
    the split, and how the positions were made."""

    faces: np.ndarray            # (T_high, 3) high-res faces
    rest_vertices: np.ndarray    # (V_high, 3) float64 subdivided rest mesh
    low_faces: np.ndarray        # (T_low, 3)
    n_low_vertices: int
    sequence: np.ndarray         # (F,) index into `names` of each frame's sequence
    sequence_frame: np.ndarray   # (F,) the frame's index within its sequence (its scene.h5 and sim files)
    names: tuple[str, ...]       # sequence names, in dataset order
    roles: tuple[str, ...]       # train or held_out, per sequence
    clips: tuple[str, ...]       # comma-separated clips each sequence plays ("" without a mannequin)
    split: Split
    frame: str                   # reference frame of the positions: world or torso
    seed: int                    # of the split
    test_fraction: float
    frame_time: float            # seconds between consecutive frames of a sequence
    task: TaskLayout | None = None   # a decoder task; None: the upsampling
    windows: tuple[dict | None, ...] = ()    # per sequence, the motion library window it plays (None: none)
    dropped: tuple[tuple[str, str], ...] = ()   # (name, reason) of each sequence dropped on the way
    subdivision: sp.csr_matrix | None = None    # the upsampling's S (V_high, V_low)


@dataclasses.dataclass(frozen=True)
class SequenceFrames:
    """One sequence's frames of the dataset, in its reference frame, and its mannequin as scene.h5 stores it."""

    inputs: np.ndarray | None    # (n, N) a decoder task's input vectors; None for the upsampling (S x_low)
    targets: np.ndarray          # (n, V_high, 3) displacements x_high - predictor
    low_positions: np.ndarray | None    # (n, V_low, 3) the upsampling's low-res run; None for a decoder task
    gravity: np.ndarray          # (n, 3) unit direction of gravity in the reference frame
    mannequin: MannequinFrames | None   # garment scenes (pipeline.artifacts.scene.read_mannequin_frames)
    capsules: tuple[np.ndarray, np.ndarray] | None   # garment scenes: end points a, b (n, P, 3) in the reference frame
    predictor: np.ndarray | None = None   # (n, V_high, 3) a decoder task's predictor; None: the inputs are it


def _utf8(texts: list[str]) -> np.ndarray:
    """Strings as a fixed-length bytes dataset holds them (UTF-8: a library's paths need not be ASCII)."""
    return np.array([text.encode() for text in texts], dtype="S")


def chunk_frames(n_vertices: int, n_frames: int) -> int:
    """Frames per chunk of the per-frame arrays: a power of two holding about CHUNK_BYTES of targets."""
    fits = max(1, CHUNK_BYTES // (n_vertices * 3 * 4))
    return max(1, min(n_frames, 2 ** int(np.log2(fits))))


def write_dataset(path: str | os.PathLike, config: Mapping[str, Any], layout: DatasetLayout,
                  sequences: Iterable[SequenceFrames], source_mesh: str | None) -> None:
    """Write the dataset, filling the frames of `sequences` (in layout order, read one at a time) in turn;
    `source_mesh` is the fingerprint of the low-res rest mesh it derives from (None: unknown, no attr)."""
    n_frames, n_vertices, task = len(layout.sequence), len(layout.rest_vertices), layout.task
    chunk = chunk_frames(n_vertices, n_frames)
    digest = hashlib.sha256()
    with atomic_h5(path, STAGE, config) as f:
        if source_mesh is not None:
            f.attrs[SOURCE_MESH] = source_mesh

        def per_frame(name: str, shape: tuple[int, ...]) -> h5py.Dataset:
            return f.create_dataset(name, (n_frames, *shape), np.float32, chunks=(chunk, *shape))

        # The arrays each sequence fills, in the order they are digested.
        if task is None:
            arrays = {"low_positions": per_frame(LOW_POSITIONS, (layout.n_low_vertices, 3))}
            write_csr(f, SUBDIVISION, layout.subdivision)
            for name in ("data", "indices", "indptr"):
                digest.update(f[f"{SUBDIVISION}/{name}"][()].tobytes())
        else:
            arrays = {"inputs": per_frame(INPUT, (task.input_size,)),
                      "predictor": per_frame(PREDICTOR, (n_vertices, 3))}
        arrays["targets"] = per_frame(TARGET, (n_vertices, 3))
        f.create_dataset(CONTEXT_GRAVITY, (n_frames, 3), np.float32)
        start = _write_frames(path, f, arrays, sequences, n_frames, task is None, digest)
        if start != n_frames:
            raise PipelineError(f"{path}: the sequences gave {start} frames, the layout says {n_frames}")
        f.attrs.update({FORMAT: DATASET_FORMAT, FRAMES_DIGEST: digest.hexdigest(), CHUNK_FRAMES: chunk})
        f.create_dataset(FACES, data=layout.faces.astype(np.int32))
        f.create_dataset(REST_VERTICES, data=layout.rest_vertices.astype(np.float64))
        if task is None:
            f.create_dataset(LOW_FACES, data=layout.low_faces.astype(np.int32))
        f.create_dataset(SEQUENCE, data=layout.sequence.astype(np.int32))
        f.create_dataset(SEQUENCE_FRAME, data=layout.sequence_frame.astype(np.int64))
        for name, values in ((SEQUENCE_NAMES, layout.names), (SEQUENCE_ROLES, layout.roles),
                             (SEQUENCE_CLIPS, layout.clips)):
            f.create_dataset(name, data=np.array(values, dtype="S"))
        if any(layout.windows):
            for key, name in WINDOW_FIELDS.items():
                f.create_dataset(name, data=_utf8([(w or {}).get(key, "") for w in layout.windows]))
            spans = [[(w or {}).get("start", -1.0), (w or {}).get("end", -1.0)] for w in layout.windows]
            f.create_dataset(SEQUENCE_SPAN, data=np.array(spans, dtype=np.float64))
            f[SEQUENCE_SPAN].attrs["meaning"] = ("per sequence, the seconds [start, end) of its library file's motion "
                                                 "that it plays (-1: not a library window)")
        if layout.dropped:
            f.create_dataset(DROPPED_NAMES, data=_utf8([n for n, _ in layout.dropped]))
            f.create_dataset(DROPPED_REASONS, data=_utf8([r for _, r in layout.dropped]))
            f[DROPPED_NAMES].attrs["meaning"] = "sequences dropped on the way and left out, with the reason of each"
        _write_split(f, layout.split)
        f.attrs.update(problem="cloth upsampling (paper Table 2)" if task is None else task.problem,
                       frame=layout.frame, n_frames=n_frames,
                       n_vertices=n_vertices, n_sequences=len(layout.names), split_seed=layout.seed,
                       test_fraction=layout.test_fraction, frame_time=layout.frame_time)
        f[CONTEXT_GRAVITY].attrs["meaning"] = "unit direction of gravity per frame, in the reference frame"
        if CONTEXT_CAPSULE_A in f:
            for name in (CONTEXT_CAPSULE_A, CONTEXT_CAPSULE_B):
                f[name].attrs["meaning"] = (f"the body capsules' end points per frame (F, P, 3) in the reference "
                                            f"frame; radii in {CAPSULE_RADIUS_A}, {CAPSULE_RADIUS_B}")
        if task is None:
            f[LOW_POSITIONS].attrs["meaning"] = ("the low-res run x_low per frame (F, V_low, 3), in the reference "
                                                 "frame; the input and predictor are S x_low")
            f[SUBDIVISION].attrs["meaning"] = "Loop subdivision S (V_high, V_low) as CSR arrays; rows sum to one"
            f[TARGET].attrs["meaning"] = "displacement x_high - S x_low, per frame (F, V_high, 3)"
        else:
            _write_task(f, task)
        f[SEQUENCE].attrs["meaning"] = ("index into sequences/names of each frame's sequence; frame f - 1 is the "
                                        "frame before f in time when both have the same sequence id")


def _write_frames(path: str | os.PathLike, f, arrays: dict[str, h5py.Dataset], sequences: Iterable[SequenceFrames],
                  n_frames: int, upsampling: bool, digest) -> int:
    """Write each sequence's frames after the last one's, adding its `arrays` to `digest` in their order; returns
    the frames written. Digesting takes about as long as writing, so it runs on a thread of its own (hashlib lets
    go of the GIL) while the next sequence is written, at most one sequence behind."""
    def digest_all(values: list[np.ndarray]) -> None:
        for value in values:
            digest.update(value)      # the array's buffer: no tobytes() copy

    start = 0
    with ThreadPoolExecutor(max_workers=1) as hasher:     # one thread: the arrays are digested in turn
        digested = hasher.submit(lambda: None)
        for part in sequences:
            rows = slice(start, start + len(part.targets))
            if any(getattr(part, name) is None for name in arrays) or (part.inputs is None) != upsampling:
                raise PipelineError(f"{path}: a sequence's frames do not fit the dataset's task")
            values = [np.ascontiguousarray(getattr(part, name), dtype=np.float32) for name in arrays]
            digested.result()
            digested = hasher.submit(digest_all, values)
            for dataset, data in zip(arrays.values(), values):
                dataset[rows] = data
            f[CONTEXT_GRAVITY][rows] = part.gravity
            if part.mannequin is not None:
                _write_mannequin(f, part.mannequin, rows, n_frames)
            if part.capsules is not None:
                for name, ends in zip((CONTEXT_CAPSULE_A, CONTEXT_CAPSULE_B), part.capsules):
                    if name not in f:
                        f.create_dataset(name, (n_frames, *ends.shape[1:]), np.float32)
                    f[name][rows] = ends
            start = rows.stop
        digested.result()
    return start


def _write_split(f, split: Split) -> None:
    """The split's frame ids and how its test frames were drawn (a windows split adds its guard frames)."""
    named = [(SPLIT_TRAIN, split.train), (SPLIT_TEST, split.test), (SPLIT_HELD_OUT, split.held_out)]
    windows = split.test_split.kind == WINDOWS
    if windows:
        named.append((SPLIT_GUARD, split.guard))
    for name, ids in named:
        f.create_dataset(name, data=np.asarray(ids, dtype=np.int64))
    f[SPLIT].attrs.update(meaning=WINDOWS_SPLIT_MEANING if windows else SPLIT_MEANING,
                          held_out_clips=",".join(split.held_out_clips))
    f.attrs[TEST_SPLIT] = split.test_split.kind
    if windows:
        f.attrs.update({TEST_WINDOW: split.test_split.window, GUARD: split.test_split.guard})


def _write_task(f, task: TaskLayout) -> None:
    """A decoder task's attrs and, for PCA, its basis."""
    f.attrs[TASK] = task.name
    f.attrs.update(task.attrs)
    f[INPUT].attrs["meaning"] = task.input_meaning
    f[PREDICTOR].attrs["meaning"] = task.predictor_meaning
    f[TARGET].attrs["meaning"] = "displacement x_high - predictor, per frame (F, V_high, 3)"
    if task.pca is not None:
        pca = task.pca
        for name, data in ((PCA_MEAN, pca.mean), (PCA_COMPONENTS, pca.components),
                           (PCA_SINGULAR_VALUES, pca.singular_values)):
            f.create_dataset(name, data=np.asarray(data, dtype=np.float64))
        f["pca"].attrs.update(explained=pca.explained, fitted_frames=pca.fitted_frames,
                              meaning="x ~ mean + sum_k input[k] components[k], components orthonormal as "
                                      "(V * 3)-vectors, fitted to the training frames of the high-res run")


def _write_mannequin(f, mannequin: MannequinFrames, rows: slice, n_frames: int) -> None:
    """One sequence's mannequin, under scene.h5's names: per-frame rows, and the constants once."""
    for name, data in mannequin.per_frame.items():
        if name not in f:
            f.create_dataset(name, (n_frames, *data.shape[1:]), data.dtype)
        f[name][rows] = data
    for name, data in mannequin.constant.items():
        if name not in f:
            f.create_dataset(name, data=data)
    for name, values in mannequin.attrs.items():
        f[name].attrs.update(values)


@dataclasses.dataclass(frozen=True)
class FrameContext:
    """What each frame's cloth moves in, in the dataset's reference frame (the network's non-cloth inputs)."""

    gravity: np.ndarray      # (F, 3) unit direction
    capsule_a: np.ndarray    # (F, P, 3) body capsules' end points; P = 0 for a scene without a body
    capsule_b: np.ndarray    # (F, P, 3)
    radius_a: np.ndarray     # (P,)
    radius_b: np.ndarray     # (P,)
    frame_time: float        # seconds between consecutive frames of a sequence


@dataclasses.dataclass(frozen=True)
class LearningData:
    """The dataset artifact's arrays: inputs, predictor and target displacements, faces, split, and what
    the network's features are made from."""

    # (F, N) a decoder task's input vectors; the upsampling's x_low (F, V_low, 3), of which the network reads
    # S x_low. None with the targets: left on disk (load_dataset(frames=False), read by a FrameReader).
    inputs: np.ndarray | None
    targets: np.ndarray | None   # (F, V, 3) x_high - predictor
    faces: np.ndarray
    rest_vertices: np.ndarray   # (V, 3) the subdivided rest mesh
    train: np.ndarray
    test: np.ndarray
    fingerprint: str
    held_out: np.ndarray   # frames of motions never trained on (may be empty)
    sequence: np.ndarray   # (F,) int64 sequence id of each frame: frame f - 1 precedes f if their ids agree
    previous: np.ndarray   # (F,) int64 the frame before each frame in its sequence (itself at a sequence's start)
    context: FrameContext
    frame: str = "world"   # reference frame of the positions
    held_out_clips: str = ""   # comma-separated motion clips of `held_out`
    task: str = UPSAMPLING     # which learning problem (pipeline/tasks)
    stored_predictor: np.ndarray | None = None   # (F, V, 3) a decoder task's predictor
    pca: PcaBasis | None = None   # the PCA task's basis
    # test split `windows`: the frames within the guard of a test frame, in no split (empty otherwise)
    guard: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    test_split: SplitRule = SplitRule()
    subdivision: sp.csr_matrix | None = None     # the upsampling's S (V, V_low)

    @functools.cached_property
    def predictor(self) -> np.ndarray:
        """(F, V, 3) float32 what the network's displacement is added to: a decoder task's stored predictor, or
        the upsampling's S x_low, computed here once (every frame's: for the evaluation's renders and exports)."""
        if self.stored_predictor is not None:
            return self.stored_predictor
        return self.subdivided(self.inputs)

    def subdivided(self, low: np.ndarray) -> np.ndarray:
        """S x_low (n, V, 3) float32 of the upsampling's low-res frames `low` (n, V_low, 3) float32, each frame the
        same bits as its row of `predictor` however many frames go together (the sparse product runs down each
        column on its own): the evaluation makes a chunk's at a time."""
        flat = self.subdivision.astype(np.float32) @ low.transpose(1, 0, 2).reshape(low.shape[1], -1)
        return np.ascontiguousarray(flat.reshape(len(self.rest_vertices), len(low), 3).transpose(1, 0, 2))

    @property
    def has_body(self) -> bool:
        """Whether the frames carry a mannequin's capsules (a garment scene), which input 'body' measures."""
        return self.context.capsule_a.shape[1] > 0

    def splits(self) -> dict[str, np.ndarray]:
        """The non-empty splits by name."""
        named = {"train": self.train, "test": self.test, "held_out": self.held_out}
        return {name: ids for name, ids in named.items() if len(ids)}


def load_dataset(path: str | os.PathLike, frames: bool = True) -> LearningData:
    """dataset.h5's contents; with `frames` False the upsampling's x_low and targets stay on disk (None): a
    dataset larger than memory, read by a `FrameReader` while training."""
    with open_artifact(path) as f:
        _check_format(f)
        task = str(f.attrs.get(TASK, UPSAMPLING))
        shapes = {name: _shape(f, name) for name in (LOW_POSITIONS if task == UPSAMPLING else INPUT, TARGET)}
        low_shape, target_shape = shapes.values()
        n_frames, n_vertices = target_shape[0], target_shape[1]
        stored_predictor, subdivision = None, None
        if task == UPSAMPLING:
            subdivision = read_csr(f, SUBDIVISION)
            if len(low_shape) != 3 or low_shape[0] != n_frames or low_shape[2] != 3 or len(target_shape) != 3 \
                    or target_shape[2] != 3 or subdivision.shape != (n_vertices, low_shape[1]):
                raise PipelineError(f"{path}: '{LOW_POSITIONS}' {low_shape}, '{TARGET}' {target_shape} and "
                                    f"'{SUBDIVISION}' {subdivision.shape} must be (F, V_low, 3), (F, V, 3) and "
                                    f"(V, V_low)")
        else:
            stored_predictor = read(f, PREDICTOR, np.float32)
            if len(target_shape) != 3 or target_shape[2] != 3 or stored_predictor.shape != target_shape \
                    or low_shape[:1] != target_shape[:1] or len(low_shape) != 2:
                raise PipelineError(f"{path}: task '{task}': '{PREDICTOR}' {stored_predictor.shape} and '{TARGET}' "
                                    f"{target_shape} must both be (F, V, 3) and '{INPUT}' {low_shape} (F, N)")
        inputs = targets = None
        if frames or task != UPSAMPLING:
            inputs = read(f, LOW_POSITIONS if task == UPSAMPLING else INPUT, np.float32)
            targets = read(f, TARGET, np.float32)
        faces = read_indices(f, FACES, n_vertices, shape=(None, 3))
        train, test = (read_indices(f, name, n_frames, shape=(None,)) for name in (SPLIT_TRAIN, SPLIT_TEST))
        held_out = read_indices(f, SPLIT_HELD_OUT, n_frames, shape=(None,))
        test_split = _read_test_split(f)
        guard = (read_indices(f, SPLIT_GUARD, n_frames, shape=(None,)) if test_split.kind == WINDOWS
                 else np.zeros(0, np.int64))
        # A dataset without sequence ids (made by hand) is one sequence.
        sequence = (read_indices(f, SEQUENCE, len(f[SEQUENCE_NAMES]), shape=(n_frames,)) if SEQUENCE in f
                    else np.zeros(n_frames, np.int64))
        frame = str(f.attrs.get("frame", "world"))
        held_out_clips = str(f[SPLIT].attrs.get("held_out_clips", ""))
        rest_vertices = read(f, REST_VERTICES, np.float64)
        if rest_vertices.shape != (n_vertices, 3):
            raise PipelineError(f"{path}: '{REST_VERTICES}' {rest_vertices.shape} must be {(n_vertices, 3)}")
        context = _read_context(f, n_frames)
        pca = _read_pca(f, low_shape[1], n_vertices) if PCA_MEAN in f else None
        frames_digest = str(f.attrs.get(FRAMES_DIGEST, ""))
    try:
        previous = previous_frames(sequence)
    except ValueError as err:
        raise PipelineError(f"{path}: '{SEQUENCE}': {err}") from None
    every = np.concatenate([train, test, held_out, guard])
    if len(train) == 0 or len(test) == 0 or len(np.unique(every)) != len(every):
        raise PipelineError(f"{path}: '{SPLIT_TRAIN}', '{SPLIT_TEST}' (and '{SPLIT_HELD_OUT}', '{SPLIT_GUARD}') "
                            f"must be disjoint frame ids, train and test non-empty")
    # The frames as the writer digested them (every frame's arrays), and what this reader takes from elsewhere.
    digest = hashlib.sha256(frames_digest.encode())
    digest.update(task.encode())
    digest.update(train.tobytes())
    for array in (context.gravity, context.capsule_a, context.capsule_b, context.radius_a, context.radius_b):
        digest.update(array.tobytes())
    return LearningData(inputs, targets, faces, rest_vertices, train, test, digest.hexdigest(), held_out, sequence,
                        previous, context, frame, held_out_clips, task, stored_predictor, pca, guard, test_split,
                        subdivision)


def read_task_attrs(path: str | os.PathLike, names: tuple[str, ...]) -> dict[str, Any] | None:
    """The root attrs `names` a task stored (TaskLayout.attrs), or None if any is missing."""
    with open_artifact(path) as f:
        if any(name not in f.attrs for name in names):
            return None
        return {name: f.attrs[name].item() if isinstance(f.attrs[name], np.generic) else f.attrs[name]
                for name in names}


def frame_bytes(path: str | os.PathLike) -> tuple[str, int]:
    """A dataset's task and the bytes of its per-frame arrays (what training keeps on the device, or streams)."""
    with open_artifact(path) as f:
        _check_format(f)
        task = str(f.attrs.get(TASK, UPSAMPLING))
        names = (LOW_POSITIONS, TARGET) if task == UPSAMPLING else (INPUT, PREDICTOR, TARGET)
        return task, sum(int(np.prod(_shape(f, name))) * 4 for name in names)


def _check_format(f) -> None:
    """One error for a dataset.h5 of another layout than this reader's (an older one stored S x_low)."""
    found = f.attrs.get(FORMAT)
    if not isinstance(found, str) or found != DATASET_FORMAT:
        made = "an older pipeline.dataset" if found is None else f"format '{found}'"
        raise PipelineError(f"{f.filename}: a dataset of {made}, not {DATASET_FORMAT} (it stored S x_low; now "
                            f"x_low and S are): make it again with pipeline.dataset")


def _shape(f, name: str) -> tuple[int, ...]:
    """The shape of a dataset of real numbers, one error naming it otherwise."""
    dataset = f.get(name)
    if not isinstance(dataset, h5py.Dataset) or dataset.dtype.kind not in "biuf":
        raise PipelineError(f"{f.filename}: missing dataset '{name}' of real numbers")
    return dataset.shape


class FrameReader:
    """An upsampling dataset's x_low and targets read by runs of frames (model.streaming.FrameSource.read),
    each read checked as `h5.read` checks a whole dataset. The file stays open until `close`."""

    def __init__(self, path: str | os.PathLike):
        self.path = str(path)
        self._file = h5py.File(path, "r")
        self._low, self._targets = self._file[LOW_POSITIONS], self._file[TARGET]

    def __call__(self, first: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        return self.low(first, stop), self.targets(first, stop)

    def low(self, first: int, stop: int) -> np.ndarray:
        """x_low of the frames [first, stop) alone (the evaluation's S x_low of the frames it keeps)."""
        return self._read(self._low, first, stop)

    def targets(self, first: int, stop: int) -> np.ndarray:
        """The targets of the frames [first, stop) alone."""
        return self._read(self._targets, first, stop)

    def _read(self, dataset: h5py.Dataset, first: int, stop: int) -> np.ndarray:
        try:
            values = dataset[first:stop]
        except Exception as err:      # h5py raises many types for a damaged file (as open_artifact says)
            raise PipelineError(f"{self.path}: frames {first}-{stop - 1} unreadable ({type(err).__name__})") from None
        with np.errstate(invalid="ignore"):
            if not np.all(np.abs(values) <= FLOAT32_MAX):
                raise PipelineError(f"{self.path}: frames {first}-{stop - 1} hold NaN or inf")
        return values.astype(np.float32, copy=False)

    def close(self) -> None:
        self._file.close()


def _read_test_split(f) -> SplitRule:
    """How the test frames were drawn (a file without attr `test_split`, made before it, drew them at random)."""
    kind = str(f.attrs.get(TEST_SPLIT, RANDOM))
    if kind == RANDOM:
        return SplitRule()
    if kind != WINDOWS:
        raise PipelineError(f"{f.filename}: attr '{TEST_SPLIT}' is '{kind}', not '{RANDOM}' or '{WINDOWS}'")
    try:
        window, guard = float(f.attrs[TEST_WINDOW]), float(f.attrs[GUARD])
    except (KeyError, TypeError, ValueError):
        raise PipelineError(f"{f.filename}: a '{WINDOWS}' test split needs attrs '{TEST_WINDOW}' and '{GUARD}' "
                            f"(seconds)") from None
    if not (np.isfinite(window) and np.isfinite(guard) and window > 0 and guard >= 0):
        raise PipelineError(f"{f.filename}: attrs '{TEST_WINDOW}' {window} and '{GUARD}' {guard} must be finite "
                            f"seconds, the window > 0 and the guard >= 0")
    return SplitRule(WINDOWS, window, guard)


def _read_pca(f, n_components: int, n_vertices: int) -> PcaBasis:
    mean, components = read(f, PCA_MEAN, np.float64), read(f, PCA_COMPONENTS, np.float64)
    singular_values = read(f, PCA_SINGULAR_VALUES, np.float64)
    if mean.shape != (n_vertices, 3) or components.shape != (n_components, n_vertices, 3) \
            or singular_values.shape != (n_components,):
        raise PipelineError(f"{f.filename}: '{PCA_MEAN}' {mean.shape}, '{PCA_COMPONENTS}' {components.shape} and "
                            f"'{PCA_SINGULAR_VALUES}' {singular_values.shape} must be ({n_vertices}, 3), "
                            f"({n_components}, {n_vertices}, 3) and ({n_components},)")
    attrs = f["pca"].attrs
    return PcaBasis(mean, components, singular_values, float(attrs.get("explained", np.nan)),
                    int(attrs.get("fitted_frames", 0)))


def _read_context(f, n_frames: int) -> FrameContext:
    if CONTEXT_GRAVITY not in f or "frame_time" not in f.attrs:
        raise PipelineError(f"{f.filename}: no '{CONTEXT_GRAVITY}' or attr 'frame_time': made by an older "
                            f"pipeline.dataset; make it again")
    frame_time = float(f.attrs["frame_time"])
    gravity = read(f, CONTEXT_GRAVITY, np.float32)
    if gravity.shape != (n_frames, 3) or not np.allclose(np.linalg.norm(gravity, axis=1), 1.0, atol=1e-4):
        raise PipelineError(f"{f.filename}: '{CONTEXT_GRAVITY}' must hold ({n_frames}, 3) unit vectors")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise PipelineError(f"{f.filename}: attr 'frame_time' must be finite and > 0, got {frame_time}")
    if CONTEXT_CAPSULE_A not in f:
        empty = np.zeros((n_frames, 0, 3), np.float32)
        return FrameContext(gravity, empty, empty, np.zeros(0, np.float32), np.zeros(0, np.float32), frame_time)
    a, b = read(f, CONTEXT_CAPSULE_A, np.float32), read(f, CONTEXT_CAPSULE_B, np.float32)
    radius_a, radius_b = read(f, CAPSULE_RADIUS_A, np.float32), read(f, CAPSULE_RADIUS_B, np.float32)
    n = len(radius_a)
    if a.shape != (n_frames, n, 3) or b.shape != a.shape or radius_b.shape != (n,) or np.any(radius_a <= 0) \
            or np.any(radius_b <= 0) or np.any(np.linalg.norm(b - a, axis=2) <= np.abs(radius_a - radius_b)):
        raise PipelineError(f"{f.filename}: '{CONTEXT_CAPSULE_A}', '{CONTEXT_CAPSULE_B}' must be ({n_frames}, "
                            f"{n}, 3) and the radii positive, each capsule longer than its radii differ")
    return FrameContext(gravity, a, b, radius_a, radius_b, frame_time)


def read_low_faces(path: str | os.PathLike) -> np.ndarray:
    """The faces (T_low, 3) int64 of the low-res mesh the dataset was made from (its positions are x_low)."""
    with open_artifact(path) as f:
        return read_indices(f, LOW_FACES, _shape(f, LOW_POSITIONS)[1], shape=(None, 3))


@dataclasses.dataclass(frozen=True)
class FrameOrigins:
    """Where the test and held-out frames of a dataset.h5 come from, and the frame its positions are in."""
    names: tuple[str, ...]          # its sequences, in dataset order
    sequence: np.ndarray            # (F,) index into `names` of each frame's sequence
    sequence_frame: np.ndarray      # (F,) the frame's index within its sequence's runs
    splits: dict[str, np.ndarray]   # "test" and, where the scene has a held-out motion, "held_out": frame ids
    torso: np.ndarray | None        # (F, 4, 4) world-from-torso per frame for a dataset in the torso frame


def read_frame_origins(path: str | os.PathLike) -> FrameOrigins:
    with open_artifact(path) as f:
        names = f.get(SEQUENCE_NAMES)
        if not isinstance(names, h5py.Dataset) or names.dtype.kind != "S" or names.ndim != 1:
            raise PipelineError(f"{path}: missing dataset '{SEQUENCE_NAMES}': not a dataset.h5 of pipeline.dataset")
        names = tuple(name.decode() for name in names[()])
        sequence = read_indices(f, SEQUENCE, len(names), shape=(None,))
        n_frames = len(sequence)
        sequence_frame = read_indices(f, SEQUENCE_FRAME, np.iinfo(np.int64).max, shape=(n_frames,))
        splits = {"test": read_indices(f, SPLIT_TEST, n_frames, shape=(None,)),
                  "held_out": read_indices(f, SPLIT_HELD_OUT, n_frames, shape=(None,))}
        frame = str(f.attrs.get("frame", "world"))
    torso = read_torso_transforms(path, n_frames) if frame == "torso" else None
    if not len(splits["test"]):
        raise PipelineError(f"{path}: '{SPLIT_TEST}' is empty")
    return FrameOrigins(names, sequence, sequence_frame, {k: v for k, v in splits.items() if len(v)}, torso)


@dataclasses.dataclass(frozen=True)
class LibraryWindows:
    """The motion-library window each sequence of a dataset plays, in dataset order ("" and span (-1, -1) for a
    sequence that plays none: a motion program, a held-out clip of the settings)."""
    file: tuple[str, ...]        # the window's file, relative to the library folder
    subject: tuple[str, ...]     # who performs it
    category: tuple[str, ...]    # the manifest's category ("" without one)
    span: np.ndarray             # (S, 2) the seconds [start, end) of the file's motion it plays


def read_library_windows(path: str | os.PathLike) -> LibraryWindows | None:
    """What each sequence plays of a motion library, or None for a dataset without library windows."""
    with open_artifact(path) as f:
        if WINDOW_FIELDS["file"] not in f:
            return None
        n_sequences = len(_texts(f, SEQUENCE_NAMES, None))
        fields = {key: _texts(f, name, n_sequences) for key, name in WINDOW_FIELDS.items()}
        span = read(f, SEQUENCE_SPAN, np.float64)
    if span.shape != (n_sequences, 2):
        raise PipelineError(f"{path}: '{SEQUENCE_SPAN}' {span.shape} must be ({n_sequences}, 2)")
    return LibraryWindows(**fields, span=span)


def read_dropped(path: str | os.PathLike) -> tuple[tuple[str, str], ...]:
    """(name, reason) of each sequence dropped on the way to the dataset (none: an empty tuple)."""
    with open_artifact(path) as f:
        if DROPPED_NAMES not in f:
            return ()
        names = _texts(f, DROPPED_NAMES, None)
        reasons = _texts(f, DROPPED_REASONS, len(names))
    return tuple(zip(names, reasons))


def _texts(f, name: str, count: int | None) -> tuple[str, ...]:
    """A 1-D dataset of UTF-8 texts (`count` of them, if given), one error naming it otherwise."""
    dataset = f.get(name)
    if not isinstance(dataset, h5py.Dataset) or dataset.dtype.kind != "S" or dataset.ndim != 1 \
            or (count is not None and len(dataset) != count):
        raise PipelineError(f"{f.filename}: '{name}' must be a list of texts"
                            + ("" if count is None else f", one per entry of the other lists ({count})"))
    try:
        return tuple(text.decode() for text in dataset[()])
    except UnicodeDecodeError:
        raise PipelineError(f"{f.filename}: '{name}' holds text that is not UTF-8") from None
