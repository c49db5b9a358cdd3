"""What the decoder tasks (pose, pca) share: a per-frame input vector, their own predictor positions, and the
report rows that describe them."""
from __future__ import annotations

import numpy as np

from pipeline.artifacts.dataset import LearningData, SequenceFrames
from pipeline.tasks.task import SequenceRun, Task


class DecoderTask(Task):
    letter = "U"
    input_description = ""     # what the input vector holds, for the report
    timed = "the network, its input vector given (the predictor, computed beside it, is not timed)"

    def input_rows(self, data: LearningData, state: dict, low_vertices: int | None = None) -> list[list]:
        return [["vertices", f"{data.targets.shape[1]} high-res"],
                ["positions in", f"the {data.frame} frame"],
                ["network input", f"{data.inputs.shape[1]} scalars per frame: {self.input_description}"],
                ["predictor", self.predictor_label]]


def decoder_frames(run: SequenceRun, inputs: np.ndarray, predictor: np.ndarray) -> SequenceFrames:
    """A decoder task's frames of one sequence: input vectors (n, N), predictor (n, V, 3), target x_high - it."""
    return SequenceFrames(inputs.astype(np.float32), (run.high - predictor).astype(np.float32), None,
                          run.gravity.astype(np.float32), run.mannequin,
                          None if run.capsules is None else tuple(e.astype(np.float32) for e in run.capsules),
                          predictor.astype(np.float32))
