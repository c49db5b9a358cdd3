"""The upsampling network on feature inputs: what NormalizedRegressor is for absolute positions.

Features of different kinds have different units (metres, metres per second, unit directions), so each feature is
centred per channel and scaled by its own RMS over the training frames (one scale per feature, so a vector's
direction is kept). The network's output is scaled back to scene units and, with `output_frame="local"`, read as
components along each vertex's local frame of S x_low and turned back into the dataset's frame, so the loss and
every consumer see ordinary displacements. All constants are buffers: they are saved with the model and add no
learnable parameters.
"""
from __future__ import annotations

import torch
from torch import nn

from model.features import FrameInputs, InputFeatures
from model.local_frames import to_global
from model.mesh_hierarchy import MeshHierarchy
from model.networks import EncoderDecoder

OUTPUT_FRAMES = ("dataset", "local")


def feature_statistics(features: torch.Tensor, groups: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean (C,) of training features (F, V, C) and, per channel, the RMS about that mean of the
    feature (group of `groups` channels) it belongs to; 1 for a feature that never varies."""
    offset = features.reshape(-1, features.shape[-1]).mean(dim=0)
    centred = features - offset
    scales, start = [], 0
    for size in groups:
        rms = centred[..., start:start + size].square().mean().sqrt()
        scales.append(torch.where(rms > 0, rms, torch.ones_like(rms)).expand(size))
        start += size
    return offset, torch.cat(scales)


class FeatureRegressor(nn.Module):
    """features(inputs) → (x - offset) / scale → mesh network → × output_scale → [from local frames]: the
    predicted displacement x_high - S x_low (B, V, 3) in the dataset's frame."""

    def __init__(self, net: EncoderDecoder, features: InputFeatures, input_offset: torch.Tensor,
                 input_scale: torch.Tensor, output_scale: float, output_frame: str = "dataset"):
        super().__init__()
        if output_frame not in OUTPUT_FRAMES:
            raise ValueError(f"output_frame must be one of {OUTPUT_FRAMES}, got '{output_frame}'")
        if net.in_channels != features.channels:
            raise ValueError(f"the network takes {net.in_channels} input channels, the features "
                             f"{list(features.names)} give {features.channels}")
        self.net, self.features, self.output_frame = net, features, output_frame
        self.register_buffer("input_offset", torch.as_tensor(input_offset, dtype=torch.float32).reshape(-1))
        self.register_buffer("input_scale", torch.as_tensor(input_scale, dtype=torch.float32).reshape(-1))
        self.register_buffer("output_scale", torch.tensor(float(output_scale)))

    def encode(self, inputs: FrameInputs) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The normalised network input (B, V, C) and, for local outputs, the frames (B, V, 3, 3) to restore them
        with. Neither depends on the weights: training may compute them once per frame and reuse them."""
        x = (self.features(inputs) - self.input_offset) / self.input_scale
        return x, self.features.frames(inputs) if self.output_frame == "local" else None

    def decode(self, x: torch.Tensor, frames: torch.Tensor | None, mesh: MeshHierarchy) -> torch.Tensor:
        """The displacement (B, V, 3) in the dataset's frame from `encode`'s outputs."""
        displacement = self.net(x, mesh) * self.output_scale
        return displacement if frames is None else to_global(frames, displacement)

    def forward(self, inputs: FrameInputs, mesh: MeshHierarchy) -> torch.Tensor:
        return self.decode(*self.encode(inputs), mesh)
