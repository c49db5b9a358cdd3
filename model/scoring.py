"""A trained network scored over every frame of a dataset a chunk of frames at a time, resident or streamed (the
evaluate stage), so that no array of every frame's positions is ever made: at 124k frames of 11,719 vertices each
such array is 17 GB.

Each chunk is predicted on the device and reduced there to a few numbers per frame: the terms of the split errors
(model.losses.frame_terms: L1, L2 squared, Ln with positions predictor + displacement, as model.training's
`split_errors` computes them over a batch) and the per-frame L1 and L2 of the displacement error, for the network
and for its predictor alone. A split's errors are then the means of its frames' terms (`FrameScores.split`): the
same figures as `split_errors` over the whole split, up to the order of the float sums. What the caller keeps of
a chunk's predictions (the frames it shows or exports, or eval.h5's rows) it takes in `on_chunk`.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np
import torch

from model.features import FrameBatch
from model.losses import LossWeights, frame_terms
from model.training import SPLIT_BATCH, Frames, in_batches, split_values

# Frames predicted together: as many as a split's errors take after each epoch of training (SPLIT_BATCH), which
# is also what a streamed problem stages.
CHUNK_FRAMES = SPLIT_BATCH
WHO = ("network", "predictor")

# Displacements of a chunk: (the ids Frames.feed yields for it, its inputs) -> (B, V, 3) on the device.
Predict = Callable[[torch.Tensor, FrameBatch], torch.Tensor]
# What the caller takes of a chunk: (its frame ids (B,) int64, consecutive, the predicted displacements).
OnChunk = Callable[[np.ndarray, torch.Tensor], None]


@dataclasses.dataclass(frozen=True)
class FrameScores:
    """Per-frame errors over every frame of a dataset, of the network and of its predictor alone."""

    terms: dict[str, np.ndarray]                    # who -> (F, 3) float64: each frame's L1, L2², Ln (frame_terms)
    per_frame: dict[str, dict[str, np.ndarray]]     # who -> l1/l2 -> (F,) float64 of the displacement error

    def split(self, who: str, ids: np.ndarray, weights: LossWeights) -> dict[str, float]:
        """L1, L2, Ln and their weighted total over the frames `ids` taken together (model.training.split_errors'
        figures): the means of the frames' terms."""
        return split_values(*self.terms[who][ids].mean(axis=0).tolist(), weights)


def score_frames(predict: Predict, frames: Frames, n_frames: int, chunk: int = CHUNK_FRAMES,
                 on_chunk: OnChunk = lambda ids, displacement: None) -> FrameScores:
    """The `n_frames` frames of `frames` (resident, or streamed: model.streaming) predicted and scored `chunk`
    frames at a time, in frame order; each chunk's predictions are handed to `on_chunk` and dropped. The numbers
    stay on the device until the end: no chunk waits for the device unless `on_chunk` reads its predictions."""
    ids = torch.arange(n_frames, device=frames.faces.device)
    terms: dict[str, list[torch.Tensor]] = {who: [] for who in WHO}
    per_frame: dict[str, list[torch.Tensor]] = {who: [] for who in WHO}
    with torch.no_grad():
        for frame_ids, batch in zip(in_batches(np.arange(n_frames), chunk), frames.feed(ids, chunk), strict=True):
            inputs = frames.store.batch(batch)
            positions, targets = inputs.positions, frames.targets[batch]
            displacement = predict(batch, inputs)
            truth = positions + targets
            # The predictor alone predicts a zero displacement: its positions are S x_low (split_errors adds a
            # zero, which changes no bit).
            for who, predicted, error in (("network", positions + displacement, displacement - targets),
                                          ("predictor", positions, -targets)):
                terms[who].append(frame_terms(predicted, truth, frames.faces))
                per_frame[who].append(torch.stack([error.abs().mean(dim=(1, 2)),
                                                   error.square().sum(dim=2).mean(dim=1).sqrt()], dim=1))
            on_chunk(frame_ids, displacement)
    as_numpy = {who: (torch.cat(terms[who]).double().cpu().numpy(), torch.cat(per_frame[who]).double().cpu().numpy())
                for who in WHO}
    return FrameScores({who: t for who, (t, _) in as_numpy.items()},
                       {who: {"l1": p[:, 0], "l2": p[:, 1]} for who, (_, p) in as_numpy.items()})
