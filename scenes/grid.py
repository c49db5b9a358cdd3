"""Procedural flat cloth pieces and the rigid drivers that move their pinned vertices."""
from __future__ import annotations

import math

import numpy as np


def grid_cloth(width: float, height: float, max_edge: float, plane: str = "xz",
               origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle split into the fewest quads for which every triangle edge is shorter than `max_edge`.

    Quads are cut along alternating diagonals so the mesh has no preferred shear direction. `plane` "xz" lays the
    cloth flat (normals +y); "xy" hangs it vertically (normals +z). `origin` is the corner at (u, v) = (0, 0);
    u runs along x and v along z (xz) or down along -y (xy), so for "xy" the first row is the top edge.
    """
    if width <= 0 or height <= 0 or max_edge <= 0:
        raise ValueError(f"cloth size and max_edge must be positive (got {width}, {height}, {max_edge})")
    # Grow the quad counts until the diagonal (the longest triangle edge) fits.
    nu, nv = max(1, math.ceil(width / max_edge)), max(1, math.ceil(height / max_edge))
    while math.hypot(width / nu, height / nv) >= max_edge:
        if width / nu >= height / nv:
            nu += 1
        else:
            nv += 1
    u, v = np.meshgrid(np.linspace(0.0, width, nu + 1), np.linspace(0.0, height, nv + 1))
    u, v = u.ravel(), v.ravel()
    zeros = np.zeros_like(u)
    if plane == "xz":
        local = np.stack([u, zeros, v], axis=1)
    elif plane == "xy":
        local = np.stack([u, -v, zeros], axis=1)
    else:
        raise ValueError(f"plane must be 'xz' or 'xy', got {plane!r}")
    vertices = local + np.asarray(origin, dtype=np.float64)

    row, col = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
    row, col = row.ravel(), col.ravel()
    a = row * (nu + 1) + col          # (col, row)
    b, c, d = a + 1, a + nu + 1, a + nu + 2  # (col+1, row), (col, row+1), (col+1, row+1)
    flip = (row + col) % 2 == 1
    tri1 = np.where(flip[:, None], np.stack([a, c, d], 1), np.stack([a, c, b], 1))
    tri2 = np.where(flip[:, None], np.stack([a, d, b], 1), np.stack([b, c, d], 1))
    return vertices, np.concatenate([tri1, tri2]).astype(np.int64)


def sway_driver(n_frames: int, dt: float, amplitude: tuple[float, float, float], period: float,
                yaw_amplitude: float, settle_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Rigid transforms (rotation (F,3,3), translation (F,3)) of a pinned rod that rests for `settle_frames`,
    then sways: a Lissajous translation (x at the period, z at half of it) and a yaw about the rod's centre.

    The motion ramps in with a smoothstep envelope so the trajectory is C1 and starts at rest.
    """
    t = (np.arange(n_frames) - settle_frames) * dt
    t = np.maximum(t, 0.0)
    ramp = np.clip(t / period, 0.0, 1.0)
    envelope = ramp * ramp * (3.0 - 2.0 * ramp)
    phase = 2.0 * np.pi * t / period
    amp = np.asarray(amplitude, dtype=np.float64)
    translation = envelope[:, None] * np.stack(
        [amp[0] * np.sin(phase), amp[1] * (1.0 - np.cos(phase)), amp[2] * np.sin(0.5 * phase)], axis=1)
    yaw = envelope * yaw_amplitude * np.sin(phase)
    cos, sin = np.cos(yaw), np.sin(yaw)
    rotation = np.zeros((n_frames, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 2] = cos, sin
    rotation[:, 1, 1] = 1.0
    rotation[:, 2, 0], rotation[:, 2, 2] = -sin, cos
    return rotation, translation


def first_row_pins(vertices: np.ndarray, plane: str, rule: str) -> np.ndarray:
    """Pinned vertex ids of a `grid_cloth`: its first row (the top edge when hanging, the -z edge when flat),
    either whole (`top_edge`) or only its two end corners (`corners`)."""
    along = vertices[:, 1] if plane == "xy" else -vertices[:, 2]
    row = np.flatnonzero(np.isclose(along, along.max()))
    row = row[np.argsort(vertices[row, 0])]
    if rule == "top_edge":
        return row
    if rule == "corners":
        return row[[0, -1]]
    raise ValueError(f"unknown pin rule {rule!r} (corners, top_edge)")
