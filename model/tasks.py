"""The decoder tasks as the stages train, save and run them: a per-frame vector (the mannequin's 208 pose scalars,
or K PCA coefficients) → fixed normalisation → decoder (Fig. 7) → the displacement from the task's predictor
(linear blend skinning, or the PCA reconstruction) in the dataset's frame (paper Table 2, rows 2 and 3).

`VectorStore.batch` answers the same question as `model.features.FrameStore.batch`: what a batch's displacement
is added to (`positions`, the predictor) and what the network reads (`values`), so one training loop
(model.training.fit) and one error measure (model.training.split_errors) serve every task.
"""
from __future__ import annotations

import dataclasses

import torch
from torch import nn

from model.feature_regressor import mean_square, with_input_noise
from model.mesh_hierarchy import MeshHierarchy
from model.networks import Decoder

STATISTICS_EPS = 1e-12      # a scalar whose training values never vary keeps scale 1


@dataclasses.dataclass(frozen=True)
class VectorBatch:
    """A batch of frames of a decoder task."""

    positions: torch.Tensor    # (B, V, 3) the predictor: what the predicted displacement is added to
    values: torch.Tensor       # (B, N) the network's input vector


@dataclasses.dataclass(frozen=True)
class VectorStore:
    """Every frame of a decoder task's dataset on one device."""

    positions: torch.Tensor    # (F, V, 3) predictor
    values: torch.Tensor       # (F, N)

    def __len__(self) -> int:
        return len(self.positions)

    def batch(self, ids: torch.Tensor) -> VectorBatch:
        return VectorBatch(self.positions[ids], self.values[ids])

    def predictor(self, ids: torch.Tensor) -> torch.Tensor:
        return self.positions[ids]


@dataclasses.dataclass(frozen=True)
class VectorSpec:
    """What the input vector is (stored in model.pt as the decoder's counterpart of FeatureSpec)."""

    inputs: tuple[str, ...]    # e.g. ("pose",) or ("pca_16",): the task's name for its vector

    def __post_init__(self):
        object.__setattr__(self, "inputs", tuple(self.inputs))
        if len(self.inputs) != 1 or not all(isinstance(n, str) and n for n in self.inputs):
            raise ValueError(f"a decoder reads one named vector, got {self.inputs!r}")


class VectorRegressor(nn.Module):
    """(values - offset) / scale → decoder → × output_scale: the displacement (B, V, 3) from the predictor.

    Each input scalar has its own offset and scale (the training mean and standard deviation): the pose vector
    mixes positions, quaternion components and velocities, and PCA coefficients fall off by orders of magnitude
    from the first to the last. The normalisation is buffers, never learned, so the parameter count is the
    decoder's (paper Table 4)."""

    def __init__(self, net: Decoder, spec: VectorSpec, input_offset: torch.Tensor | None = None,
                 input_scale: torch.Tensor | None = None, output_scale: float = 1.0):
        super().__init__()
        self.net, self.spec = net, spec
        size = net.n_inputs
        offset = torch.zeros(size) if input_offset is None else input_offset
        scale = torch.ones(size) if input_scale is None else input_scale
        self.register_buffer("input_offset", torch.as_tensor(offset, dtype=torch.float32).reshape(-1))
        self.register_buffer("input_scale", torch.as_tensor(scale, dtype=torch.float32).reshape(-1))
        self.register_buffer("output_scale", torch.tensor(float(output_scale)))
        self.input_noise = 0.0   # training only (model.feature_regressor.with_input_noise); not saved

    def normalise(self, store: VectorStore, train_ids: torch.Tensor, targets: torch.Tensor) -> None:
        """Fix the normalisations from the training frames `train_ids` only: per-scalar mean and standard
        deviation of the inputs, and the RMS of their target displacements (of every frame's `targets`)."""
        values = store.values[train_ids].double()
        mean, std = values.mean(dim=0), values.std(dim=0, unbiased=False)
        self.input_offset.copy_(mean)
        self.input_scale.copy_(torch.where(std > STATISTICS_EPS, std, torch.ones_like(std)))
        self.output_scale.fill_(mean_square(targets, train_ids) ** 0.5 or 1.0)

    def forward(self, inputs: VectorBatch, mesh: MeshHierarchy) -> torch.Tensor:
        z = with_input_noise((inputs.values - self.input_offset) / self.input_scale, self.input_noise, self.training)
        return self.net(z, mesh) * self.output_scale
