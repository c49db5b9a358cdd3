"""One upsampling network on several meshes (paper sec. 7, supplementary Table 3): shared weights, and per mesh
its own operator tables and feature constants.

A mesh CNN's weights do not depend on the mesh: a convolution gathers each vertex's table row and multiplies by
one (L*C, C_out) matrix, whatever the mesh. So a network for many garments is one `EncoderDecoder` and, per
garment, a `FeatureRegressor` over that same network (its faces and rest positions for the input features) run
on that garment's `MeshHierarchy`. Instance norm is taken per frame, so frames of different meshes never mix
inside the network; only the loss and the optimiser step see them together.

Batches (`MultiMeshFrames`): a sample is one frame of every garment, and a batch of B samples is B frames of
each garment, so every optimiser step sees every garment. Its loss is the mean over garments of each garment's
batch loss (eq. 7 over its B frames, exactly what one-garment training computes), so each garment weighs the
same whatever its vertex count, and one garment's loss and gradient are those of its own training. Garments with
fewer frames in a split than the largest repeat some, evenly spread (frame floor(k n_g / N) of sample k), so an
epoch shows every frame of every garment at least once. (Round-robin, one garment per step, would let Adam's
moments swing from garment to garment; batches drawn from the pooled frames would leave some garment out of 7
steps in 9 with three garments at the paper's batch size 3, and weigh garments by their frame counts.)

The input and output normalisation is one for all garments (a network that reads the same numbers the same
way on any mesh): each garment's statistics (model.feature_regressor.store_statistics, the RMS of its training
displacements) averaged over garments, offsets as they are, scales as root mean squares, each garment weighing
the same as in the loss. With one garment it is that garment's own normalisation.
"""
from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np
import torch
from torch import nn

from model.feature_regressor import FeatureRegressor, FeatureSpec, mean_square, store_statistics
from model.losses import LossWeights
from model.mesh_hierarchy import MeshHierarchy
from model.networks import EncoderDecoder
from model.training import Frames, in_batches


class UnknownMeshError(ValueError):
    """A mesh the network was not trained on."""


class MultiMeshRegressor(nn.Module):
    """One encoder-decoder (`net`, the only learnable part) and its normalisation, shared by the garments of
    `meshes` (name -> (faces, subdivided rest positions)); `part(name)` is the garment's `FeatureRegressor`, whose
    `net` is this one's.

    The parts are kept in a plain dict, not registered as submodules: each holds `net`, and registered they would
    put the shared weights into the state dict once more per garment. So the state dict (what a training
    checkpoint holds) is `net`'s alone: the normalisation and mesh constants are fixed from the data before
    training, which the checkpoint's identity pins. `train`/`eval` and `.to`/`.cpu` reach the parts explicitly."""

    def __init__(self, net: EncoderDecoder, spec: FeatureSpec, meshes: Mapping[str, tuple[np.ndarray, np.ndarray]]):
        super().__init__()
        if not meshes:
            raise ValueError("a multi-mesh network needs at least one mesh")
        self.net, self.spec = net, spec
        self.parts = {name: FeatureRegressor(net, spec, faces, rest) for name, (faces, rest) in meshes.items()}

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.parts)

    def part(self, name: str) -> FeatureRegressor:
        """The regressor of mesh `name`; UnknownMeshError for a mesh it was not built for."""
        if name not in self.parts:
            raise UnknownMeshError(f"the network was trained on {', '.join(self.parts)}; not on '{name}'")
        return self.parts[name]

    @property
    def input_noise(self) -> float:
        return next(iter(self.parts.values())).input_noise

    @input_noise.setter
    def input_noise(self, std: float) -> None:
        for part in self.parts.values():
            part.input_noise = std

    def train(self, mode: bool = True) -> MultiMeshRegressor:
        super().train(mode)
        for part in self.parts.values():
            part.train(mode)
        return self

    def _apply(self, fn, recurse=True):
        # .to(), .cpu(), .float() ... all come here; the parts' buffers (feature constants, normalisation) move
        # with the shared network (applied to it again: already converted, a no-op).
        super()._apply(fn, recurse)
        for part in self.parts.values():
            part._apply(fn, recurse)
        return self

    def normalise(self, garments: Sequence[Garment]) -> None:
        """Fix the one normalisation from every garment's training frames: the garments' own statistics
        averaged, offsets as they are, scales and the output scale as root mean squares (module docstring)."""
        offsets, scale_squares, target_squares = [], [], []
        for garment in garments:
            offset, scale = store_statistics(self.part(garment.name).features, garment.frames.store, garment.train)
            offsets.append(offset.double())
            scale_squares.append(scale.double().square())
            target_squares.append(mean_square(garment.frames.targets, garment.train))
        output_scale = (sum(target_squares) / len(target_squares)) ** 0.5 or 1.0
        for part in self.parts.values():
            part.input_offset.copy_(torch.stack(offsets).mean(dim=0))
            part.input_scale.copy_(torch.stack(scale_squares).mean(dim=0).sqrt())
            part.output_scale.fill_(output_scale)


@dataclasses.dataclass(frozen=True)
class Garment:
    """One mesh's learning problem: its frames (model.training.Frames), the hierarchy its part runs on, and its
    train and test frame ids."""

    name: str
    frames: Frames
    mesh: MeshHierarchy
    train: torch.Tensor
    test: torch.Tensor


def spread(ids: torch.Tensor, count: int) -> torch.Tensor:
    """`count` >= len(ids) entries of `ids` for samples 0..count-1: entry floor(k len / count) for sample k, so
    every id appears at least once and the repeats are evenly spread."""
    if count < len(ids) or len(ids) == 0:
        raise ValueError(f"cannot spread {len(ids)} frames over {count} samples")
    return ids[torch.arange(count, device=ids.device) * len(ids) // count]


class MultiMeshFrames:
    """The frames of several garments as `model.training.fit` takes a problem: a sample is one frame of every
    garment; samples 0..N_train-1 are training frames (`train_samples`), the next N_test test frames
    (`test_samples`), N_split being the most frames any garment has in that split. `fit`'s `mesh` is the
    garments' hierarchies by name, its model a `MultiMeshRegressor`."""

    def __init__(self, garments: Sequence[Garment]):
        if not garments or len({g.name for g in garments}) != len(garments):
            raise ValueError("give at least one garment, each name once")
        self.garments = tuple(garments)
        n_train, n_test = (max(len(getattr(g, split)) for g in garments) for split in ("train", "test"))
        # (samples, garments): each sample's frame id in each garment's frames.
        self.table = torch.stack([torch.cat([spread(g.train, n_train), spread(g.test, n_test)]) for g in garments],
                                 dim=1)
        device = garments[0].train.device
        self.train_samples = torch.arange(n_train, device=device)
        self.test_samples = torch.arange(n_train, n_train + n_test, device=device)

    @property
    def meshes(self) -> dict[str, MeshHierarchy]:
        return {g.name: g.mesh for g in self.garments}

    def frame_ids(self, samples: torch.Tensor) -> list[torch.Tensor]:
        """Per garment, the frames of `samples` (a frame repeated in the table appears as often as it does)."""
        rows = self.table[samples]
        return [rows[:, k] for k in range(len(self.garments))]

    def feed(self, ids: torch.Tensor, batch_size: int):
        return in_batches(ids, batch_size)

    def batch_loss(self, model: MultiMeshRegressor, mesh: Mapping[str, MeshHierarchy], ids: torch.Tensor,
                   weights: LossWeights) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The mean over garments of each garment's eq. 7 over its frames of the samples `ids`, and the terms
        likewise."""
        losses = [g.frames.batch_loss(model.part(g.name), mesh[g.name], frames, weights)
                  for g, frames in zip(self.garments, self.frame_ids(ids))]
        total = torch.stack([loss for loss, _ in losses]).mean()
        terms = {name: torch.stack([t[name] for _, t in losses]).mean() for name in losses[0][1]}
        return total, terms

    def errors(self, model: MultiMeshRegressor, mesh: Mapping[str, MeshHierarchy], ids: torch.Tensor,
               batch_size: int, weights: LossWeights) -> dict[str, float]:
        """The mean over garments of each garment's split errors over its frames of the samples `ids`, each frame
        once (model.training.split_errors)."""
        per_garment = [g.frames.errors(model.part(g.name), mesh[g.name], torch.unique(frames), batch_size, weights)
                       for g, frames in zip(self.garments, self.frame_ids(ids))]
        return {name: float(np.mean([e[name] for e in per_garment])) for name in per_garment[0]}
