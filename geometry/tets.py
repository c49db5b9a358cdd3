"""Tet meshes: signed volumes, the tets of a structured grid, and the quality measures of tets.

A grid's cube is cut into the six Kuhn (Freudenthal) tets along its main diagonal, each the path 000 -> 111 over
one order of the three axes. The cut is the same in every cube, so neighbouring cubes' faces match (the mesh is
conforming) and every tet is congruent to every other: minimum dihedral angle 45 degrees and radius ratio
0.717 by construction, whatever is clipped away.
"""
from __future__ import annotations

import itertools

import numpy as np


def tet_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (T,): positive when (x1 - x0, x2 - x0, x3 - x0) is right-handed."""
    x = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]
    return np.einsum("ij,ij->i", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])) / 6.0

# Each Kuhn tet's corners as cube-corner offsets (one per order of the axes), oriented positively below.
_KUHN = np.array([[(0, 0, 0), tuple(np.eye(3, dtype=int)[p[0]]),
                   tuple(np.eye(3, dtype=int)[p[0]] + np.eye(3, dtype=int)[p[1]]), (1, 1, 1)]
                  for p in itertools.permutations(range(3))])


def kuhn_grid(cells: tuple[int, int, int], origin: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ((nx+1)(ny+1)(nz+1), 3), node (i, j, k) at origin + spacing (i, j, k) with index (i (ny+1) + j)
    (nz+1) + k, and the 6 nx ny nz positively oriented tets (T, 4) of the cells."""
    nx, ny, nz = cells
    if min(cells) < 1 or not spacing > 0:
        raise ValueError(f"a grid needs at least one cell along each axis and a positive spacing; got {cells}, "
                         f"{spacing}")
    index = np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nx + 1, ny + 1, nz + 1)
    ijk = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    nodes = np.asarray(origin, dtype=np.float64) + spacing * ijk.reshape(-1, 3)
    corner = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 1, 1, 3)
    at = corner + _KUHN[None]                                      # (cells, 6, 4, 3) integer corners
    tets = index[at[..., 0], at[..., 1], at[..., 2]].reshape(-1, 4)
    flip = tet_volumes(nodes, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return nodes, tets


def dihedral_angles(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 6) interior dihedral angles in degrees, one at each edge."""
    x = np.asarray(vertices, dtype=np.float64)[tets]
    # Face i is the one opposite corner i, its normal pointing out of the positively oriented tet.
    faces = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)]
    normals = np.stack([np.cross(x[:, b] - x[:, a], x[:, c] - x[:, a]) for a, b, c in faces], 1)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    pairs = list(itertools.combinations(range(4), 2))
    cos = np.stack([-np.einsum("ij,ij->i", normals[:, i], normals[:, j]) for i, j in pairs], 1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def radius_ratios(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) 3 r_in / r_circ: 1 for the regular tet, 0 for a flat one."""
    x = np.asarray(vertices, dtype=np.float64)[tets]
    volume = np.abs(tet_volumes(vertices, tets))
    area = sum(0.5 * np.linalg.norm(np.cross(x[:, b] - x[:, a], x[:, c] - x[:, a]), axis=1)
               for a, b, c in [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)])
    r_in = 3.0 * volume / area
    # Circumcentre c solves 2 (x_i - x_0) . c = |x_i|^2 - |x_0|^2 (relative to x_0).
    e = x[:, 1:] - x[:, :1]
    centre = np.linalg.solve(2.0 * e, np.einsum("tij,tij->ti", e, e)[..., None])[..., 0]
    return 3.0 * r_in / np.linalg.norm(centre, axis=1)
