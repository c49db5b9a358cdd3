"""Cloth upsampling (paper Table 2, row 1): the input is the Loop-subdivided low-res run S x_low, which is also the
predictor; the encoder-decoder reads per-vertex features of it (model.features)."""
from __future__ import annotations

import numpy as np

from pipeline.artifacts.dataset import LearningData, SequenceFrames
from pipeline.tasks.task import DatasetRequest, SequenceRun, Task


class UpsamplingTask(Task):
    name = "upsampling"
    letter = "D"
    predictor_label = "Loop subdivision"
    input_label = "low-res input"
    timed = "input features and network, S x_low given"
    timing_reference = ("Paper Table 3 (RTX 2080 Ti, C++/cuBLAS, including GPU Loop subdivision): 2.2-26.6 ms for "
                        "4k-15k vertices.")

    def prepare(self, request: DatasetRequest):
        S = request.subdivision.S

        def frames(run: SequenceRun) -> SequenceFrames:
            subdivided = np.stack([S @ x for x in run.low])
            return SequenceFrames(subdivided.astype(np.float32), (run.high - subdivided).astype(np.float32),
                                  run.low.astype(np.float32), run.gravity.astype(np.float32), run.mannequin,
                                  None if run.capsules is None else tuple(e.astype(np.float32) for e in run.capsules))
        return None, frames

    def input_rows(self, data: LearningData, state: dict, low_vertices: int | None = None) -> list[list]:
        features = state["features"]      # model.feature_regressor.FeatureSpec as saved
        axes = {"local": f"each vertex's local frame (tangent: {features['frame_tangent']})",
                "dataset": "the dataset's axes"}
        return [["vertices", f"{low_vertices} low-res -> {data.inputs.shape[1]} high-res"],
                ["positions in", f"the {data.frame} frame"],
                ["network inputs (model.features)", ", ".join(features["inputs"])],
                ["input vectors in", axes[features["input_frame"]]],
                ["displacement predicted in", axes[features["output_frame"]]]]
