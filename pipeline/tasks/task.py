"""What a learning problem of paper Table 2 supplies to the shared learning stages (SpiralNet++ style: one module
per application over shared operators, networks and stages).

A task says what the network reads (its inputs), what it adds its output to (the predictor), hence its target
(x_high - predictor), which network reads such inputs and how it is built, fed, timed and shown (an
encoder-decoder reads per-vertex features, a decoder one vector per frame), and how a report names the predictor.
The dataset stage asks the task for each sequence's frames; `train` and `evaluate` read the task from dataset.h5,
ask it everything that depends on the network's kind, and are otherwise the same for every task.
"""
from __future__ import annotations

import abc
import dataclasses
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np
import torch

from geometry.rigid import apply_rigid_inverse
from model.architecture import ArchitectureError
from model.mesh_hierarchy import MeshHierarchy
from model.networks import MeshNetwork, NetworkSpec, build_network
from model.regressors import Regressor
from model.training import Frames
from pipeline.artifacts.dataset import DatasetLayout, FrameReader, LearningData, SequenceFrames, TaskLayout
from pipeline.artifacts.scene import MannequinFrames
from pipeline.artifacts.subdiv import Subdivision
from pipeline.core.errors import PipelineError
from pipeline.tasks.timing import InferenceTimes


@dataclasses.dataclass(frozen=True, eq=False)
class SequenceRun:
    """One sequence as the dataset stage reads it, its kept frames in the dataset's reference frame."""

    where: Path                    # its scene.h5, or its folder without one (for error messages)
    low: np.ndarray                # (n, V_low, 3) float64 low-res run
    high: np.ndarray               # (n, V_high, 3) float64 high-res run
    transforms: np.ndarray | None  # (n, 4, 4) world-from-reference per frame; None in the world frame
    gravity: np.ndarray            # (n, 3) unit direction in the reference frame
    mannequin: MannequinFrames | None
    capsules: tuple[np.ndarray, np.ndarray] | None   # end points a, b (n, P, 3) in the reference frame


def in_reference_frames(transforms: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (n, P, 3) of n frames, each in its frame's reference frame (world-from-reference transforms (n, 4, 4)),
    float64. apply_rigid_inverse one frame at a time: the same bits as `transforms[:, None]` broadcast over all
    frames in one call, which einsum ran ~7 times slower (0.81 s against 0.12 s for 397 frames of 11,719 vertices)."""
    out = np.empty(points.shape, np.result_type(transforms, points))
    for frame, (transform, frame_points) in enumerate(zip(transforms, points)):
        out[frame] = apply_rigid_inverse(transform, frame_points)
    return out


# Frames of one sequence for the dataset, from its run.
FrameMaker = Callable[[SequenceRun], SequenceFrames]


@dataclasses.dataclass(frozen=True)
class DatasetRequest:
    """What the dataset stage gives a task to prepare its frames with."""

    layout: DatasetLayout
    subdivision: Subdivision
    runs: Callable[[], Iterable[SequenceRun]]     # every sequence's run, in dataset order, read afresh per call
    shared_scene: Path | None                     # the first sequence's scene.h5 (skeleton, skinning)
    components: int | None                        # --components (PCA)


# Frames [first, stop) of a dataset -> one array per frame.
FrameRun = Callable[[int, int], np.ndarray]


@dataclasses.dataclass(frozen=True)
class HostFrames:
    """A dataset's frames on the host as the evaluation stores, exports and shows them, a run of frames at a time
    (from memory, or from disk for a dataset too large for it): never every frame at once."""

    input_faces: np.ndarray     # (T_in, 3) faces of a picture's first panel: what the network is given, as a mesh
    input_vertices: int         # its vertices
    inputs: FrameRun            # (n, V_in, 3) its positions
    predictor: FrameRun         # (n, V, 3) float32 what the displacement is added to: LearningData.predictor's rows
    targets: FrameRun           # (n, V, 3) float32 x_high - predictor


@dataclasses.dataclass(frozen=True)
class NetworkKind:
    """The network a task trains, as its architecture string writes it (docs/architecture.md, "Grammar")."""

    name: str          # in reports and messages: "encoder-decoder", "decoder"
    letter: str        # the token letter its architecture is written with
    example: str       # an architecture of this kind, for messages

    def check(self, arch: str, refusal: str) -> None:
        """One error, `refusal`, unless `arch` is written with this kind's tokens."""
        if arch.strip()[:1] != self.letter:
            raise PipelineError(refusal)

    def __str__(self) -> str:
        return f"{'an' if self.name[0] in 'aeiou' else 'a'} {self.name}, written with {self.letter} tokens (e.g. " \
               f"'{self.example}')"


@dataclasses.dataclass(frozen=True)
class NetworkRequest:
    """The network a training asks for: train's --arch, --conv, --pool, --width and the per-vertex input flags
    (settings `network.*`)."""

    arch: str
    conv: str
    pool: str
    width: float
    features: Mapping[str, Any]    # inputs, input_frame, output_frame, frame_tangent (core.config.feature_spec)
    features_source: str           # how an error names where `features` came from


@dataclasses.dataclass(frozen=True, eq=False)
class Trainable:
    """A task's freshly initialised network, wrapped in its regressor, and the operators' levels it runs on."""

    spec: NetworkSpec              # complete: what model.pt stores to rebuild the network
    model: Regressor
    mesh: MeshHierarchy


def network_of(spec: NetworkSpec) -> MeshNetwork:
    """The network `spec` describes, initialised from torch's seeded generator; one error naming the flags."""
    try:
        return build_network(spec)
    except ArchitectureError as err:
        raise PipelineError(f"--arch/--conv/--pool/--width: {err}") from None


def check_fits(net: MeshNetwork, mesh: MeshHierarchy, operators: str) -> None:
    """One error naming the operators file unless `net` can run on its levels `mesh`."""
    try:
        net.check_mesh(mesh)
    except ValueError as err:
        raise PipelineError(f"{operators}: {err}") from None


class Task(abc.ABC):
    """One learning problem; the subclasses are the applications (pipeline/tasks/<name>.py), each of which must
    say how its frames are made (`prepare`) and what its network reads (`input_rows`); the network kinds
    (encoder-decoder, decoder: upsampling.py, decoder.py) say how their network is built, fed, timed and shown."""

    name = ""
    network: NetworkKind      # the network this task trains
    predictor_label = ""      # "Loop subdivision": how reports name the predictor
    input_label = ""          # the first panel of a render: what the network is given, as a mesh
    truth_label = "high-res ground truth"    # the second: what it is trained towards
    timing_reference = ""     # the paper's figures to compare the inference time with
    timed = ""                # what the inference time covers
    streams = False           # whether training may read its frames from disk a batch at a time (streamed_frames)

    @abc.abstractmethod
    def prepare(self, request: DatasetRequest) -> tuple[TaskLayout | None, FrameMaker]:
        """The task's part of dataset.h5's layout (None: the upsampling's) and how a run becomes frames."""

    @abc.abstractmethod
    def input_rows(self, data: LearningData, state: dict, low_vertices: int | None = None) -> list[list]:
        """Rows of a report's "Inputs" table describing what the network read."""

    @abc.abstractmethod
    def build(self, request: NetworkRequest, data: LearningData, operators: str, dataset: str) -> Trainable:
        """The network `request` describes for this task's `data` (read from `dataset`), on the levels of the
        `operators` file it needs, wrapped in the regressor that feeds it."""

    @abc.abstractmethod
    def frames(self, data: LearningData, device: torch.device | str) -> Frames:
        """Every frame of the dataset on `device` as the network reads them, each with the predictor it adds to."""

    @abc.abstractmethod
    def trained_on(self, model: Regressor, mesh: MeshHierarchy, data: LearningData) -> bool:
        """Whether `model` (on its operators' levels `mesh`) was trained on `data`'s mesh."""

    @abc.abstractmethod
    def host_frames(self, data: LearningData, dataset: str, reader: FrameReader | None) -> HostFrames:
        """The frames of `data` (read from `dataset`) on the host, from `data` or, for a dataset loaded without
        its frames (load_dataset(frames=False)), through `reader`."""

    @abc.abstractmethod
    def time(self, model: Regressor, mesh: MeshHierarchy, store, ids: torch.Tensor,
             fused: bool = True) -> InferenceTimes:
        """Milliseconds per frame of the network on each frame of `ids`, as pipeline.tasks.timing measures it;
        `fused`: also the fused bf16 network where the task has one and the device runs it."""

    def check_arch(self, arch: str) -> None:
        """One error naming --arch unless `arch` writes this task's kind of network."""
        self.network.check(arch, f"--arch '{arch}': the network of task '{self.name}' is {self.network}")

    def check_model(self, state: dict, model_path: str, dataset_path: str) -> None:
        """One error unless the model.pt `state` holds a network of this task's kind."""
        self.network.check(state["spec"]["arch"], f"{model_path}: not a network of task '{self.name}' (the task "
                                                  f"of {dataset_path})")

    def extra_error_rows(self, errors: dict, splits: list[str]) -> list[list]:
        """Rows the task adds under the error table's gain row (none by default)."""
        return []

    def error_note(self, data: LearningData) -> str:
        """A sentence on what the predictor is, for the report (empty by default)."""
        return ""

    def timing_note(self, dataset: str, network_ms: float) -> str:
        """Sentences the report's inference time adds: what the network replaces costs, against its median
        `network_ms` (empty by default)."""
        return ""
