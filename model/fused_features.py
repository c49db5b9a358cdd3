"""model.features' input features (and the local frames) of a frame in one kernel launch (model.triton_features):
the CUDA deployment path's features, beside the fused network. Covers the features a per-vertex pass can compute
(`COVERED`); a spec with another (a per-frame mean, strains, the previous output) keeps model.features' PyTorch
path (`covers`).

The mesh's tables are built once here: for each vertex its faces' other two corners in the face's winding order
(the face's cross product from that corner is the face's own), its neighbours, valence and reference neighbour;
short rows are padded with -1.
"""
from __future__ import annotations

import os

import numpy as np
import torch
from torch import nn

from geometry.mesh import unique_edges
from model.feature_spec import FEATURE_CHANNELS, FeatureSpec
from model.features import FrameBatch, reference_neighbours

# The features the kernel computes, in the order of its layout argument (model.triton_features.features).
COVERED = ("position", "rest_position", "normal", "laplacian", "velocity", "acceleration", "body", "gravity")


def padded_rows(owners: np.ndarray, values: np.ndarray, n_rows: int) -> np.ndarray:
    """(n_rows, W, ...) int32: row r lists the `values` whose owner is r, in the given order, padded with -1 to
    the longest row (W >= 1)."""
    order = np.argsort(owners, kind="stable")
    owners, values = owners[order], values[order]
    counts = np.bincount(owners, minlength=n_rows)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(owners)) - starts[owners]
    table = np.full((n_rows, max(int(counts.max(initial=0)), 1), *values.shape[1:]), -1, dtype=np.int32)
    table[owners, slot] = values
    return table


def corner_table(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V, F, 2): for each face a vertex is in, the face's next two corners after it (winding order kept)."""
    faces = np.asarray(faces, dtype=np.int64)
    owners = faces.ravel()
    following = np.stack([faces[:, [1, 2, 0]].ravel(), faces[:, [2, 0, 1]].ravel()], axis=-1)
    return padded_rows(owners, following, n_vertices)


def neighbour_table(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V, N): each vertex's neighbours along the mesh's edges."""
    edges = unique_edges(np.asarray(faces))
    return padded_rows(np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]]),
                       n_vertices)


class FusedFeatures(nn.Module):
    """`InputFeatures.with_frames` for a covered spec in one Triton kernel (CUDA, or Triton's interpreter)."""

    def __init__(self, spec: FeatureSpec, faces: np.ndarray, rest_positions: np.ndarray):
        super().__init__()
        if not self.covers(spec):
            raise ValueError(f"the fused features compute {', '.join(COVERED)}; got {', '.join(spec.inputs)}")
        n_vertices = len(rest_positions)
        neighbours = neighbour_table(faces, n_vertices)
        self.register_buffer("corners", torch.as_tensor(corner_table(faces, n_vertices)))
        self.register_buffer("neighbours", torch.as_tensor(neighbours))
        self.register_buffer("valence", torch.as_tensor((neighbours >= 0).sum(axis=1), dtype=torch.float32))
        self.register_buffer("reference", torch.as_tensor(reference_neighbours(faces, n_vertices).astype(np.int32)))
        self.register_buffer("rest", torch.as_tensor(np.asarray(rest_positions), dtype=torch.float32).contiguous())
        offsets, channel = dict.fromkeys(COVERED, -1), 0
        for name in spec.inputs:
            offsets[name], channel = channel, channel + FEATURE_CHANNELS[name]
        self.layout = [offsets[name] for name in COVERED] + [channel]
        self.local_inputs, self.gravity_tangent = spec.input_frame == "local", spec.frame_tangent == "gravity"

    @staticmethod
    def covers(spec: FeatureSpec) -> bool:
        return all(name in COVERED for name in spec.inputs)

    def with_frames(self, inputs: FrameBatch, want_frames: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The features (B, V, C) and, where `want_frames`, the local frames (B, V, 3, 3)."""
        if not (inputs.positions.is_cuda or os.environ.get("TRITON_INTERPRET") == "1"):
            raise ValueError("the fused features run on CUDA (InputFeatures is the CPU path)")
        from model.triton_features import features     # Triton: with PyTorch's CUDA builds, not the CPU install

        frame_time = inputs.frame_time
        if frame_time is not None and not isinstance(frame_time, torch.Tensor):
            # A fill, not a copy from the host: capturable in a CUDA graph.
            frame_time = torch.full((1,), float(frame_time), device=inputs.positions.device)
        contiguous = lambda x: None if x is None else x.float().contiguous()  # noqa: E731
        stacked, frames = features(
            contiguous(inputs.positions), contiguous(inputs.previous), contiguous(inputs.before_previous),
            self.rest, contiguous(inputs.capsule_a), contiguous(inputs.capsule_b), contiguous(inputs.radius_a),
            contiguous(inputs.radius_b), contiguous(inputs.gravity),
            None if frame_time is None else frame_time.float().reshape(1), self.corners, self.neighbours,
            self.valence, self.reference, self.layout, self.local_inputs, want_frames, self.gravity_tangent)
        return stacked, frames.view(*stacked.shape[:2], 3, 3) if want_frames else None
