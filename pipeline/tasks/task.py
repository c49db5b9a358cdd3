"""What a learning problem of paper Table 2 supplies to the shared learning stages (SpiralNet++ style: one module
per application over shared operators, networks and stages).

A task says what the network reads (its inputs), what it adds its output to (the predictor), hence its target
(x_high - predictor), which network reads such inputs (an encoder-decoder reads per-vertex features, a decoder
one vector per frame), and how a report names the predictor. The dataset stage asks the task for each
sequence's frames; `train` and `evaluate` read the task from dataset.h5 and are otherwise the same for every
task.
"""
from __future__ import annotations

import abc
import dataclasses
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from pipeline.artifacts.dataset import DatasetLayout, LearningData, SequenceFrames, TaskLayout
from pipeline.artifacts.scene import MannequinFrames
from pipeline.artifacts.subdiv import Subdivision


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


class Task(abc.ABC):
    """One learning problem; the subclasses are the applications (pipeline/tasks/<name>.py), each of which must
    say how its frames are made (`prepare`) and what its network reads (`input_rows`)."""

    name = ""
    letter = ""               # the network: D (encoder-decoder on per-vertex features) or U (decoder from a vector)
    predictor_label = ""      # "Loop subdivision": how reports name the predictor
    input_label = ""          # the first panel of a render: what the network is given, as a mesh
    timing_reference = ""     # the paper's figures to compare the inference time with
    timed = ""                # what the inference time covers

    @abc.abstractmethod
    def prepare(self, request: DatasetRequest) -> tuple[TaskLayout | None, FrameMaker]:
        """The task's part of dataset.h5's layout (None: the upsampling's) and how a run becomes frames."""

    @abc.abstractmethod
    def input_rows(self, data: LearningData, state: dict) -> list[list]:
        """Rows of a report's "Inputs" table describing what the network read."""

    def extra_error_rows(self, errors: dict, splits: list[str]) -> list[list]:
        """Rows the task adds under the error table's gain row (none by default)."""
        return []

    def error_note(self, data: LearningData) -> str:
        """A sentence on what the predictor is, for the report (empty by default)."""
        return ""
