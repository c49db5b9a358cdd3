"""Per-vertex orthonormal frames of a deforming surface, to express displacements (or input vectors) relative to
the coarse surface instead of the dataset's axes.

A wrinkle is mostly a displacement along the surface normal whatever way the garment faces; in each vertex's own
frame the same wrinkle on a turned leg is the same numbers, so a network predicting local displacements need not
learn every orientation (Zhang & Li 2024 predict in the coarse faces' frames). The frame of vertex i has rows
(tangent, bitangent, normal): the normal given, the tangent a direction projected onto the tangent plane, the
bitangent their cross product. The direction is either the edge to a fixed neighbour (each vertex's own, so
tangents of neighbouring vertices point anywhere relative to each other) or a hint shared by all vertices, such as
gravity (tangents then vary smoothly over the surface). Being orthonormal, the frame turns vectors both ways exactly
(up to rounding).
"""
from __future__ import annotations

import torch

_EPS = 1e-12
# Weight of the reference edge next to a hint: keeps the tangent defined where the surface faces along the hint
# (a horizontal patch under an upward hint) while turning it by at most ~3 degrees elsewhere.
EDGE_TIE_BREAK = 0.05


def _unit_tangent(vectors: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    tangent = vectors - (vectors * normals).sum(-1, keepdim=True) * normals
    return tangent / tangent.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def vertex_frames(positions: torch.Tensor, normals: torch.Tensor, reference: torch.Tensor,
                  hint: torch.Tensor | None = None) -> torch.Tensor:
    """Frames (B, V, 3, 3), rows tangent, bitangent, normal, from positions and unit normals (B, V, 3) and each
    vertex's reference neighbour (V,) int64 (model.features.reference_neighbours); with `hint` (B, 3), the
    tangent is the hint's projection (the reference edge only breaking ties, EDGE_TIE_BREAK).

    Without a hint the tangent is undefined only where the reference edge is parallel to the normal, which a cloth
    mesh whose normals average its incident faces does not produce short of a fully folded vertex fan.
    """
    tangent = _unit_tangent(positions[:, reference] - positions, normals)
    if hint is not None:
        unit_hint = hint / hint.norm(dim=-1, keepdim=True).clamp_min(_EPS)
        tangent = _unit_tangent(unit_hint[:, None, :].expand_as(normals), normals) + EDGE_TIE_BREAK * tangent
        tangent = tangent / tangent.norm(dim=-1, keepdim=True).clamp_min(_EPS)
    bitangent = torch.linalg.cross(normals, tangent, dim=-1)
    return torch.stack([tangent, bitangent, normals], dim=-2)


def to_local(frames: torch.Tensor, vectors: torch.Tensor) -> torch.Tensor:
    """Vectors (B, V, 3) in the dataset frame → components along each vertex's (tangent, bitangent, normal)."""
    return torch.einsum("bvij,bvj->bvi", frames, vectors)


def to_global(frames: torch.Tensor, local: torch.Tensor) -> torch.Tensor:
    """Inverse of `to_local`: local components (B, V, 3) → vectors in the dataset frame."""
    return torch.einsum("bvji,bvj->bvi", frames, local)
