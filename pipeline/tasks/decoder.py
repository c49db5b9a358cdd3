"""What the decoder tasks (pose, pca) share: a per-frame input vector, their own predictor positions, the decoder
(Fig. 7) that reads the vector, and the report rows that describe them."""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from model.architecture import ArchitectureError, parse_architecture
from model.networks import NetworkSpec
from model.tasks import VectorRegressor, VectorSpec, VectorStore
from model.training import Frames
from pipeline.artifacts.dataset import FrameReader, LearningData, SequenceFrames
from pipeline.artifacts.operators import load_hierarchy
from pipeline.core.errors import PipelineError
from pipeline.tasks.task import (HostFrames, NetworkKind, NetworkRequest, SequenceRun, Task, Trainable, check_fits,
                                 network_of)
from pipeline.tasks.timing import time_decoder


class DecoderTask(Task):
    network = NetworkKind("decoder", "U", "U208 U U208 U U208 U U208 U104 U52 U3")
    input_description = ""     # what the input vector holds, for the report
    timed = "the network, its input vector given (the predictor, computed beside it, is not timed)"

    def input_rows(self, data: LearningData, state: dict, low_vertices: int | None = None) -> list[list]:
        return [["vertices", f"{data.targets.shape[1]} high-res"],
                ["positions in", f"the {data.frame} frame"],
                ["network input", f"{data.inputs.shape[1]} scalars per frame: {self.input_description}"],
                ["predictor", self.predictor_label]]

    def build(self, request: NetworkRequest, data: LearningData, operators: str, dataset: str) -> Trainable:
        """The decoder from the task's input vector onto the coarsest level its tokens reach: its fully connected
        layer depends on that level's vertex count, so the operators are read first."""
        self.check_arch(request.arch)
        spec = NetworkSpec(request.arch, request.conv, request.pool, request.width, data.inputs.shape[1],
                           data.targets.shape[2])
        try:
            n_levels = parse_architecture(spec.arch, self.network.letter).n_pooling + 1
        except ArchitectureError as err:
            raise PipelineError(f"--arch/--conv/--pool/--width: {err}") from None
        mesh = load_hierarchy(operators, spec.conv, n_levels, data.faces, dataset)
        spec = dataclasses.replace(spec, coarse_vertices=mesh.vertex_counts[-1])
        net = network_of(spec)
        check_fits(net, mesh, operators)
        return Trainable(spec, VectorRegressor(net, VectorSpec((self.name,))), mesh)

    def frames(self, data: LearningData, device: torch.device | str) -> Frames:
        store = VectorStore(torch.as_tensor(data.predictor, device=device),
                            torch.as_tensor(data.inputs, device=device))
        return Frames(store, torch.as_tensor(data.targets, device=device),
                      torch.as_tensor(data.faces.astype(np.int64), device=device))

    def trained_on(self, model, mesh, data: LearningData) -> bool:
        # The operators' level 0 is the mesh the decoder writes (load_model checked they are its own).
        return mesh.vertex_counts[0] == data.targets.shape[1]

    def host_frames(self, data: LearningData, dataset: str, reader: FrameReader | None) -> HostFrames:
        """Every frame resident (a decoder task's dataset is never streamed); the first panel is the predictor."""
        def predictor(first: int, stop: int) -> np.ndarray:
            return data.predictor[first:stop]
        return HostFrames(data.faces, data.targets.shape[1], predictor, predictor,
                          lambda first, stop: data.targets[first:stop])

    def time(self, model, mesh, store, ids: torch.Tensor, fused: bool = True):
        return time_decoder(model, mesh, store, ids)     # a decoder has no fused network


def decoder_frames(run: SequenceRun, inputs: np.ndarray, predictor: np.ndarray) -> SequenceFrames:
    """A decoder task's frames of one sequence: input vectors (n, N), predictor (n, V, 3), target x_high - it."""
    return SequenceFrames(inputs.astype(np.float32), (run.high - predictor).astype(np.float32), None,
                          run.gravity.astype(np.float32), run.mannequin,
                          None if run.capsules is None else tuple(e.astype(np.float32) for e in run.capsules),
                          predictor.astype(np.float32))
