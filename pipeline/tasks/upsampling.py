"""Cloth upsampling (paper Table 2, row 1): the input is the Loop-subdivided low-res run S x_low, which is also the
predictor; the encoder-decoder reads per-vertex features of it (model.features). The dataset holds x_low and S;
S x_low is computed on the training's device, batch by batch (model.features.FrameStore)."""
from __future__ import annotations

import numpy as np
import torch

from model.feature_regressor import FeatureRegressor
from model.features import FrameStore, Subdivider
from model.streaming import FrameSource, StreamedFrames
from model.networks import NetworkSpec
from model.training import Frames
from pipeline.artifacts.dataset import FrameReader, LearningData, SequenceFrames, read_low_faces
from pipeline.artifacts.operators import load_hierarchy
from pipeline.core.config import feature_spec
from pipeline.tasks.task import (DatasetRequest, HostFrames, NetworkKind, NetworkRequest, SequenceRun, Task,
                                 Trainable, check_fits, network_of)
from pipeline.tasks.timing import time_inference

BLOCK_FRAMES = 32        # frames whose targets are made at once (9 MB of float64 S x_low at 11,719 vertices)


class UpsamplingTask(Task):
    name = "upsampling"
    network = NetworkKind("encoder-decoder", "D", "D62 D124 D248 D D248 D_3 D248")
    predictor_label = "Loop subdivision"
    streams = True
    input_label = "low-res input"
    timed = "input features and network, S x_low given"
    timing_reference = ("Paper Table 3 (RTX 2080 Ti, C++/cuBLAS, including GPU Loop subdivision): 2.2-26.6 ms for "
                        "4k-15k vertices.")

    def prepare(self, request: DatasetRequest):
        S = request.subdivision.S

        def frames(run: SequenceRun) -> SequenceFrames:
            return SequenceFrames(None, displacements(S, run.low, run.high),
                                  run.low.astype(np.float32), run.gravity.astype(np.float32), run.mannequin,
                                  None if run.capsules is None else tuple(e.astype(np.float32) for e in run.capsules))
        return None, frames

    def input_rows(self, data: LearningData, state: dict, low_vertices: int | None = None) -> list[list]:
        features = state["features"]      # model.feature_regressor.FeatureSpec as saved
        axes = {"local": f"each vertex's local frame (tangent: {features['frame_tangent']})",
                "dataset": "the dataset's axes"}
        return [["vertices", f"{low_vertices} low-res -> {len(data.rest_vertices)} high-res"],
                ["positions in", f"the {data.frame} frame"],
                ["network inputs (model.features)", ", ".join(features["inputs"])],
                ["input vectors in", axes[features["input_frame"]]],
                ["displacement predicted in", axes[features["output_frame"]]]]

    def build(self, request: NetworkRequest, data: LearningData, operators: str, dataset: str) -> Trainable:
        self.check_arch(request.arch)
        features = feature_spec(request.features, data.has_body, f"{dataset}: {request.features_source}")
        spec = NetworkSpec(request.arch, request.conv, request.pool, request.width, features.channels, 3)
        net = network_of(spec)
        mesh = load_hierarchy(operators, spec.conv, net.n_levels, data.faces, dataset)
        check_fits(net, mesh, operators)
        return Trainable(spec, FeatureRegressor(net, features, data.faces, data.rest_vertices), mesh)

    def frames(self, data: LearningData, device: torch.device | str) -> Frames:
        """Every frame's x_low, S and what the input features are made from (the previous frame, the body's
        capsules, gravity), as tensors on `device`."""
        def tensor(array: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(array, device=device)

        context = data.context
        targets = tensor(data.targets)
        store = FrameStore(tensor(data.inputs), subdivider(data, device), tensor(data.previous),
                           tensor(context.capsule_a), tensor(context.capsule_b), tensor(context.radius_a),
                           tensor(context.radius_b), tensor(context.gravity), context.frame_time, targets)
        return Frames(store, targets, tensor(data.faces.astype(np.int64)))

    def streamed_frames(self, data: LearningData, reader: FrameReader, capacity: int, device: torch.device,
                        window: int) -> StreamedFrames:
        """The frames of `data` (loaded without them) read by `reader` into a staging area of `capacity` frames
        on `device`, `window` frames of an epoch's order at a time (model.streaming)."""
        context = data.context
        source = FrameSource(reader, len(data.sequence), data.previous, context.capsule_a, context.capsule_b,
                             context.radius_a, context.radius_b, context.gravity, context.frame_time)
        return StreamedFrames.create(source, subdivider(data, device),
                                     torch.as_tensor(data.faces.astype(np.int64), device=device),
                                     len(data.rest_vertices), capacity, device, window)

    def trained_on(self, model, mesh, data: LearningData) -> bool:
        return np.array_equal(model.features.faces.cpu().numpy(), data.faces)

    def host_frames(self, data: LearningData, dataset: str, reader: FrameReader | None) -> HostFrames:
        low = reader.low if reader is not None else lambda first, stop: data.inputs[first:stop]
        return HostFrames(read_low_faces(dataset), data.subdivision.shape[1],
                          lambda first, stop: low(first, stop).astype(np.float64),
                          lambda first, stop: data.subdivided(low(first, stop)),
                          reader.targets if reader is not None else lambda first, stop: data.targets[first:stop])

    def time(self, model, mesh, store, ids: torch.Tensor, fused: bool = True):
        return time_inference(model, mesh, store, ids, fused)


def displacements(S, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The targets x_high - S x_low (n, V_high, 3) of the runs (n, V_low, 3) and (n, V_high, 3): the float64
    difference rounded to float32, BLOCK_FRAMES frames at a time, so that the float64 temporaries are a few MB
    reused from block to block rather than fresh pages the size of the sequence."""
    out = np.empty(high.shape, np.float32)
    for first in range(0, len(low), BLOCK_FRAMES):
        block = slice(first, first + BLOCK_FRAMES)
        np.subtract(high[block], subdivide_frames(S, low[block]), out=out[block], casting="same_kind")
    return out


def subdivide_frames(S, positions: np.ndarray) -> np.ndarray:
    """S x for every frame x of `positions` (n, V_low, 3): (n, V_high, 3) float64. One sparse product with the
    frames side by side as columns, several times faster than one per frame and the same bits: each entry sums the
    same products of its row of S in the same order."""
    n, n_low, _ = positions.shape
    side_by_side = S @ positions.transpose(1, 0, 2).reshape(n_low, 3 * n)
    return np.ascontiguousarray(side_by_side.reshape(S.shape[0], n, 3).transpose(1, 0, 2))


def subdivider(data: LearningData, device: torch.device | str) -> Subdivider:
    S = data.subdivision
    return Subdivider(S.indptr, S.indices, S.data, device)
