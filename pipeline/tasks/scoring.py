"""The evaluate stage's pass over every frame of a dataset, resident or streamed as training decides
(pipeline.tasks.streams_frames): the frames on the device, how the network predicts them (frame by frame, or rolled
out for a network that reads its own previous output), and what is kept of each chunk's predictions
(`FrameOutputs`). model.scoring runs the pass and scores the frames.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from model.autoregressive import reads_previous_output, rollout
from model.scoring import CHUNK_FRAMES, Predict
from model.training import Frames
from pipeline.artifacts.dataset import FrameReader, LearningData
from pipeline.core.errors import PipelineError
from pipeline.tasks.task import HostFrames, Task
from viz.comparison import FrameMeshes

# Frames a streamed evaluation reads from disk at once: runs of consecutive frames, since it reads them in order
# (one read per run, model.streaming), of ~70 MB at the paper's pants, read ahead by the loader's thread.
STREAM_READ_FRAMES = 512


def evaluation_frames(task: Task, data: LearningData, reader: FrameReader | None, device: torch.device) -> Frames:
    """Every frame of `data` on `device`, or for a dataset loaded without its frames a staging area of a chunk
    filled from `reader` (model.streaming)."""
    if reader is None:
        return task.frames(data, device)
    return task.streamed_frames(data, reader, CHUNK_FRAMES, device, STREAM_READ_FRAMES)


def network_predict(model, mesh, frames: Frames, streamed: bool, n_bytes: int, dataset: str) -> Predict:
    """How the pass predicts a chunk: the network on its inputs, or for a network that reads its previous output
    each sequence rolled out from its first frame first (model.autoregressive: every frame's output at once, so a
    resident dataset only, as training refuses a streamed one)."""
    if not reads_previous_output(model):
        return lambda ids, inputs: model(inputs, mesh)
    if streamed:
        raise PipelineError(f"{dataset}: a network that reads its previous output is rolled out over every frame at "
                            f"once, which a streamed dataset does not hold: give --device-cache-gb room for "
                            f"{n_bytes / 2 ** 30:.1f} GiB")
    rolled = rollout(lambda inputs: model(inputs, mesh), frames.store, CHUNK_FRAMES)
    return lambda ids, inputs: rolled[ids]


class FrameOutputs:
    """What the evaluation keeps of each chunk's predictions (model.scoring's `on_chunk`): every frame's predicted
    positions handed to `store` (eval.h5's rows; None: not stored), the first `n_export` frames' to `export` one
    frame at a time, and the frames `shown` (stills, videos, GLB) whole, in `meshes`: the only frames held until
    the end. Positions are the predictor plus the displacement on the host, as `LearningData.predictor` makes
    them, so that eval.h5 and the exports hold the bits an evaluation of every frame at once held."""

    def __init__(self, host: HostFrames, shown: np.ndarray, n_export: int,
                 export: Callable[[int, np.ndarray], None], store: Callable[[int, np.ndarray], None] | None):
        self.host, self.shown, self.n_export, self.export, self.store = host, shown, n_export, export, store
        self.meshes: dict[int, FrameMeshes] = {}

    def __call__(self, ids: np.ndarray, displacement: torch.Tensor) -> None:
        first, stop = int(ids[0]), int(ids[-1]) + 1
        shown = self.shown[(self.shown >= first) & (self.shown < stop)]
        if self.store is None and first >= self.n_export and not len(shown):
            return           # nothing kept: the displacements stay on the device
        predictor = self.host.predictor(first, stop)
        predicted = predictor + displacement.cpu().numpy()
        if self.store is not None:
            self.store(first, predicted)
        for frame in range(first, min(stop, self.n_export)):
            self.export(frame, predicted[frame - first])
        if len(shown):
            inputs, targets = self.host.inputs(first, stop), self.host.targets(first, stop)
            for frame in shown - first:
                # Copies: a view would hold the whole chunk.
                self.meshes[first + int(frame)] = FrameMeshes(inputs[frame].copy(), predictor[frame].copy(),
                                                              predictor[frame] + targets[frame],
                                                              predicted[frame].copy())
