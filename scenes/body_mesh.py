"""A triangle mesh of the mannequin's capsules in one pose, for renders and tests."""
from __future__ import annotations

import numpy as np

from geometry.rotations import UNIT_X, UNIT_Y
from scenes.capsules import capsules_world
from scenes.skeleton import Skeleton


def body_mesh(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray],
              segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the body for one pose: one closed, outward-oriented surface per capsule (they overlap
    where parts meet; each is watertight). `segments` vertices around each ring; each cap has segments // 4
    rings. Returns vertices (P * (2 + 2 * k * segments), 3) and faces, part p's vertices contiguous."""
    if segments < 3:
        raise ValueError(f"segments must be at least 3, got {segments}")
    a, b, ra, rb = capsules_world(skel, transforms)
    if a.ndim != 2:
        raise ValueError("body_mesh takes the transforms of a single pose")
    rings = max(2, segments // 4)
    axis = b - a
    length = np.linalg.norm(axis, axis=1)
    unit = axis / length[:, None]
    e1 = np.cross(unit, np.where(np.abs(unit[:, 1:2]) < 0.9, UNIT_Y, UNIT_X))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(unit, e1)
    # Normal direction angle psi from -axis: sphere a up to the tangent ring psi_c = pi/2 + phi, then sphere b.
    psi_c = 0.5 * np.pi + np.arcsin((ra - rb) / length)
    fa = np.arange(1, rings + 1) / rings
    fb = np.arange(rings) / rings
    psi = np.concatenate([np.outer(psi_c, fa), psi_c[:, None] + np.outer(np.pi - psi_c, fb)], axis=1)  # (P, 2k)
    center = np.concatenate([np.repeat(a[:, None], rings, 1), np.repeat(b[:, None], rings, 1)], axis=1)
    radius = np.concatenate([np.repeat(ra[:, None], rings, 1), np.repeat(rb[:, None], rings, 1)], axis=1)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    radial = (np.cos(phi)[None, :, None] * e1[:, None, :] + np.sin(phi)[None, :, None] * e2[:, None, :])
    normal = (-np.cos(psi)[:, :, None, None] * unit[:, None, None, :]
              + np.sin(psi)[:, :, None, None] * radial[:, None, :, :])                         # (P, 2k, S, 3)
    ring_points = center[:, :, None, :] + radius[:, :, None, None] * normal
    poles = np.stack([a - ra[:, None] * unit, b + rb[:, None] * unit], axis=1)                  # (P, 2, 3)
    per_part = 2 + 2 * rings * segments
    vertices = np.concatenate([poles[:, :1], ring_points.reshape(len(a), -1, 3), poles[:, 1:]], axis=1)
    faces = _closed_tube_faces(2 * rings, segments)
    all_faces = faces[None] + per_part * np.arange(len(a))[:, None, None]
    return vertices.reshape(-1, 3), all_faces.reshape(-1, 3).astype(np.int64)


def _closed_tube_faces(n_rings: int, segments: int) -> np.ndarray:
    """Faces of a pole (vertex 0), n_rings rings of `segments` vertices running counter-clockwise about the
    axis, and a second pole (last vertex), outward when the rings advance along the axis."""
    ring = 1 + np.arange(n_rings)[:, None] * segments + np.arange(segments)[None, :]
    nxt = np.roll(ring, -1, axis=1)
    last = 1 + n_rings * segments
    south = np.stack([np.zeros(segments, dtype=np.int64), nxt[0], ring[0]], axis=1)
    north = np.stack([ring[-1], nxt[-1], np.full(segments, last)], axis=1)
    r00, r01, r10, r11 = ring[:-1], nxt[:-1], ring[1:], nxt[1:]
    bands = np.concatenate([np.stack([r00, r01, r11], -1).reshape(-1, 3), np.stack([r00, r11, r10], -1).reshape(-1, 3)])
    return np.concatenate([south, bands, north])
