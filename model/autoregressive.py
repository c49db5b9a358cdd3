"""A network that reads its own previous output (the `previous_output` feature): how it is trained and run.

A single frame's low-res state underdetermines its wrinkles, which depend on the cloth's history; GDSR (Zhang & Li
2024) feeds the network's previous output back in, frame after frame. Run that way, the network meets its own
errors as inputs, so training on the truth alone (teacher forcing) leaves it unprepared for them. Here each
training frame's previous output is the network's own, made one step earlier from the truth before it (the
"pushforward" of Brandstetter et al. 2022: one unrolled step, without gradient through it), and the evaluation
rolls each sequence out from its first frame (zero previous output, as in training) feeding every prediction to
the next frame.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np
import torch

from model.features import FrameBatch, FrameStore

FEATURE = "previous_output"


def reads_previous_output(model) -> bool:
    """Whether `model` (a FeatureRegressor, or any network without a feature spec) reads its previous output."""
    spec = getattr(model, "spec", None)
    return FEATURE in getattr(spec, "inputs", ())


def pushforward_inputs(predict: Callable[[FrameBatch], torch.Tensor], store: FrameStore,
                       ids: torch.Tensor) -> FrameBatch:
    """The inputs of the frames `ids` with, as previous output, what `predict` makes of each previous frame when
    given the truth before that (no gradient); zero at a sequence's first frame. The store must hold the true
    displacements (FrameStore.displacements)."""
    previous = store.previous[ids]
    with torch.no_grad():
        own = predict(store.batch(previous))
    first = (previous == ids)[:, None, None]
    return dataclasses.replace(store.batch(ids), previous_output=torch.where(first, torch.zeros_like(own), own))


def rollout(predict: Callable[[FrameBatch], torch.Tensor], store: FrameStore, batch_size: int) -> torch.Tensor:
    """Every frame's displacement (F, V, 3), each sequence run from its first frame with the network's previous
    output fed back: the frames at the same step of their sequences go together, `batch_size` at a time."""
    previous = store.previous.cpu().numpy()
    steps = steps_into_sequence(previous)
    out: torch.Tensor | None = None
    with torch.no_grad():
        for step in range(int(steps.max(initial=-1)) + 1):
            at_step = np.flatnonzero(steps == step)
            for start in range(0, len(at_step), batch_size):
                ids = torch.as_tensor(at_step[start:start + batch_size], device=store.previous.device)
                inputs = store.batch(ids)
                fed = (torch.zeros_like(inputs.positions) if step == 0
                       else out[store.previous[ids]])
                displacement = predict(dataclasses.replace(inputs, previous_output=fed))
                if out is None:
                    out = displacement.new_zeros((len(previous), *displacement.shape[1:]))
                out[ids] = displacement
    return out if out is not None else torch.zeros(0)


def steps_into_sequence(previous: np.ndarray) -> np.ndarray:
    """Each frame's step from its sequence's first frame (F,), from previous-frame ids (a first frame is its own
    previous). Frames are stored in time order, so one pass suffices."""
    steps = np.zeros(len(previous), np.int64)
    for frame, before in enumerate(previous):
        if before != frame:
            if before > frame:
                raise ValueError(f"frame {frame}'s previous frame {before} comes after it: frames are not in time "
                                 f"order")
            steps[frame] = steps[before] + 1
    return steps
