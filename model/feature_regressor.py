"""The upsampling network as the stages train, save and run it: input features of a batch of frames, fixed
normalisations, the mesh CNN, and the displacement back in the dataset's frame.

`FeatureSpec` names what the network sees (model.features): the paper's absolute positions, or inputs relative to
the body and the local surface, which is what lets it meet motions it was never trained on (issue 11, measured in
docs/performance.md). Features of different kinds have different units (metres, metres per second, unit
directions), so each feature is centred per channel and scaled by its own RMS over the training frames. The
network's output is scaled back to scene units and, with `output_frame="local"`, read as components along each
vertex's local frame of S x_low and turned back into the dataset's frame, so the loss and every consumer see
ordinary displacements.
"""
from __future__ import annotations


import numpy as np
import torch
from torch import nn

from model.feature_spec import FeatureSpec
from model.features import FrameBatch, FrameStore, InputFeatures
from model.local_frames import to_global
from model.mesh_hierarchy import MeshHierarchy
from model.networks import EncoderDecoder

STATISTICS_FRAMES = 512                # training frames the normalisation is measured on (evenly spread)


def store_statistics(features: InputFeatures, store: FrameStore, ids: torch.Tensor,
                     batch_size: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean (C,) of the features of the frames `ids` of a store and, per channel, the RMS about that
    mean of the feature (group of channels) it belongs to, 1 for a feature that never varies: one scale per
    feature keeps a vector's direction. Measured on at most STATISTICS_FRAMES of the frames (evenly spread), a
    batch at a time, so that no copy of every frame's features is ever held."""
    if len(ids) > STATISTICS_FRAMES:
        ids = ids[torch.linspace(0, len(ids) - 1, STATISTICS_FRAMES).round().long()]
    with torch.no_grad():
        batches = [ids[i:i + batch_size] for i in range(0, len(ids), batch_size)]
        total = sum(features(store.batch(b)).double().sum(dim=(0, 1)) for b in batches)
        offset = total / (len(ids) * len(features.rest))
        squares = sum((features(store.batch(b)).double() - offset).square().sum(dim=(0, 1)) for b in batches)
    per_channel = squares / (len(ids) * len(features.rest))
    scales, start = [], 0
    for size in features.groups():
        rms = per_channel[start:start + size].mean().sqrt()
        scales.append(torch.where(rms > 0, rms, torch.ones_like(rms)).expand(size))
        start += size
    return offset.float(), torch.cat(scales).float()


def with_input_noise(z: torch.Tensor, std: float, training: bool) -> torch.Tensor:
    """`z` plus Gaussian noise of standard deviation `std` while training, `z` itself otherwise. Applied to the
    normalised inputs (each channel has unit training variance, so `std` is a fraction of each channel's spread):
    a regulariser (noise on the inputs acts like a penalty on the network's input gradients, Bishop 1995) meant to
    keep the map smooth where an unseen motion puts inputs between the training frames'. Draws from torch's
    default generator, which the training checkpoint saves and a CUDA graph replays safely."""
    return z + std * torch.randn_like(z) if training and std > 0 else z


def mean_square(targets: torch.Tensor, ids: torch.Tensor, batch_size: int = 256) -> float:
    """Mean of the squared entries of `targets[ids]` (float64 sums), a batch of frames at a time: a copy of every
    training frame's targets (3 GB in float64 for 64 paper-profile sequences) would crowd other trainings out of
    a shared GPU. `targets` is anything that gives the targets of a tensor of frame ids (a streamed dataset's
    are read from disk: model.streaming.DiskStore)."""
    total, count = 0.0, 0
    with torch.no_grad():
        for i in range(0, len(ids), batch_size):
            batch = targets[ids[i:i + batch_size]]
            total, count = total + float(batch.double().square().sum()), count + batch.numel()
    return total / max(1, count)


class FeatureRegressor(nn.Module):
    """features(inputs) → (x - offset) / scale → mesh network → × output_scale → [from local frames]: the
    predicted displacement x_high - S x_low (B, V, 3) in the dataset's frame.

    The mesh constants of the features (faces, rest positions) and the normalisation are buffers: saved with the
    model, moved by `.to(device)`, never learned."""

    def __init__(self, net: EncoderDecoder, spec: FeatureSpec, faces: np.ndarray, rest_positions: np.ndarray,
                 input_offset: torch.Tensor | None = None, input_scale: torch.Tensor | None = None,
                 output_scale: float = 1.0):
        super().__init__()
        if net.in_channels != spec.channels:
            raise ValueError(f"the network takes {net.in_channels} input channels, the inputs "
                             f"{', '.join(spec.inputs)} give {spec.channels}")
        self.net, self.spec, self.features = net, spec, InputFeatures.of(spec, faces, rest_positions)
        offset = torch.zeros(spec.channels) if input_offset is None else input_offset
        scale = torch.ones(spec.channels) if input_scale is None else input_scale
        self.register_buffer("input_offset", torch.as_tensor(offset, dtype=torch.float32).reshape(-1))
        self.register_buffer("input_scale", torch.as_tensor(scale, dtype=torch.float32).reshape(-1))
        self.register_buffer("output_scale", torch.tensor(float(output_scale)))
        self.input_noise = 0.0   # training only (with_input_noise); not part of the saved model

    def normalise(self, store: FrameStore, train_ids: torch.Tensor, targets: torch.Tensor) -> None:
        """Fix the normalisations from the training frames `train_ids` only: the inputs' (store_statistics) and
        the RMS of their target displacements (of every frame's `targets`; rotation-invariant, so the same in
        local frames)."""
        offset, scale = store_statistics(self.features, store, train_ids)
        self.input_offset.copy_(offset)
        self.input_scale.copy_(scale)
        self.output_scale.fill_(mean_square(targets, train_ids) ** 0.5 or 1.0)

    def encode(self, inputs: FrameBatch) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The normalised network input (B, V, C) and, for local outputs, the frames (B, V, 3, 3) to restore them
        with. Neither depends on the weights: a caller may compute them once per frame and reuse them."""
        features, frames = self.features.with_frames(inputs, self.spec.output_frame == "local")
        return with_input_noise((features - self.input_offset) / self.input_scale, self.input_noise,
                                self.training), frames

    def decode(self, x: torch.Tensor, frames: torch.Tensor | None, mesh: MeshHierarchy) -> torch.Tensor:
        """The displacement (B, V, 3) in the dataset's frame from `encode`'s outputs."""
        displacement = self.net(x, mesh) * self.output_scale
        return displacement if frames is None else to_global(frames, displacement)

    def forward(self, inputs: FrameBatch, mesh: MeshHierarchy) -> torch.Tensor:
        return self.decode(*self.encode(inputs), mesh)
