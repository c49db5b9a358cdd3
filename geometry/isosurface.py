"""The zero set of a function sampled at the nodes of a tet mesh (marching tetrahedra), and an even remeshing of it
on an implicit surface.

Marching tetrahedra has no ambiguous cases (unlike marching cubes), so on a conforming tet mesh whose node values
are never exactly zero the triangles form a closed, consistently oriented 2-manifold: every crossing point is on
a mesh edge and is shared by every tet around that edge. Its triangles are uneven (a crossing near a node makes a
sliver), so `relax_on_surface` moves each vertex towards the mean of its neighbours within the tangent plane and
back onto the implicit surface, which evens the edge lengths while the connectivity stays.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

# Node values closer to zero than this share of the spacing are moved off zero (outward): a zero node value would
# put a crossing point on the node itself, shared by tets that do not share an edge, and break the manifold.
ZERO_OFFSET = 1.0e-9


def _ring(code: int) -> list[tuple[int, int]] | None:
    """The tet edges (corner pairs) a cut crosses, in order around it, for the corners inside given as bits of
    `code`: three around a lone corner, four around a quad."""
    inside = [c for c in range(4) if code >> c & 1]
    outside = [c for c in range(4) if not code >> c & 1]
    if len(inside) in (0, 4):
        return None
    if len(inside) != 2:
        lone = inside[0] if len(inside) == 1 else outside[0]
        return [(lone, b) for b in range(4) if b != lone]
    (a, b), (c, d) = inside, outside
    return [(a, c), (a, d), (b, d), (b, c)]


_RINGS = [_ring(code) for code in range(16)]


def marching_tetrahedra(nodes: np.ndarray, tets: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3) of {values = 0} interpolated linearly in each tet, oriented with their
    normals towards positive values."""
    values = np.asarray(values, dtype=np.float64)
    scale = float(np.abs(values).max()) or 1.0
    values = np.where(np.abs(values) < ZERO_OFFSET * scale, ZERO_OFFSET * scale, values)
    pattern = (values[tets] < 0) @ (1 << np.arange(4))
    edge_keys, triangles = [], []
    for code, ring in enumerate(_RINGS):
        cut = tets[pattern == code]
        if ring is None or not len(cut):
            continue
        ring = np.array(ring)
        ends = np.sort(np.stack([cut[:, ring[:, 0]], cut[:, ring[:, 1]]], axis=2), axis=2)     # (n, k, 2)
        base = sum(len(k) for k in edge_keys) + np.arange(len(cut))[:, None] * len(ring)
        edge_keys.append(ends.reshape(-1, 2))
        fan = [(0, 1, 2)] if len(ring) == 3 else [(0, 1, 2), (0, 2, 3)]
        triangles.extend((base + np.array(f)).reshape(-1, 3) for f in fan)
    if not edge_keys:
        raise ValueError("the function does not change sign on the mesh: there is no surface")
    keys = np.concatenate(edge_keys)
    unique, index = np.unique(keys, axis=0, return_inverse=True)
    faces = index.ravel()[np.concatenate(triangles)]
    va, vb = values[unique[:, 0]], values[unique[:, 1]]
    s = (va / (va - vb))[:, None]
    vertices = (1 - s) * nodes[unique[:, 0]] + s * nodes[unique[:, 1]]
    return vertices, _orient(vertices, faces, nodes, unique, values)


def _orient(vertices, faces, nodes, edges, values) -> np.ndarray:
    """Each triangle wound so that its normal points from the negative end of its first vertex's edge to the
    positive one."""
    v = vertices[faces]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    edge = edges[faces[:, 0]]
    up = nodes[edge[:, 1]] - nodes[edge[:, 0]]
    up *= np.sign(values[edge[:, 1]] - values[edge[:, 0]])[:, None]
    flip = np.einsum("ij,ij->i", normal, up) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def project_onto_surface(points: np.ndarray, sdf: Callable[[np.ndarray], np.ndarray], step: float,
                         iterations: int = 3) -> np.ndarray:
    """Newton steps x <- x - f(x) grad f / |grad f|^2 onto {f = 0}, the gradient by central differences of `step`."""
    for _ in range(iterations):
        grad = np.stack([(sdf(points + step * e) - sdf(points - step * e)) / (2 * step) for e in np.eye(3)], 1)
        points = points - (sdf(points) / np.maximum((grad ** 2).sum(axis=1), 1e-12))[:, None] * grad
    return points


def relax_on_surface(vertices: np.ndarray, faces: np.ndarray, sdf: Callable[[np.ndarray], np.ndarray],
                     iterations: int, step: float) -> np.ndarray:
    """`iterations` rounds of: half-way to the neighbours' mean, that move's normal part removed, then back onto
    {sdf = 0}. `step` is the finite-difference step of the normals (a small share of the edge length)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    degree = np.bincount(edges[:, 0], minlength=len(vertices))
    x = np.asarray(vertices, dtype=np.float64)
    for _ in range(iterations):
        mean = np.zeros_like(x)
        np.add.at(mean, edges[:, 0], x[edges[:, 1]])
        move = 0.5 * (mean / degree[:, None] - x)
        grad = np.stack([(sdf(x + step * e) - sdf(x - step * e)) / (2 * step) for e in np.eye(3)], 1)
        normal = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
        move -= np.einsum("ij,ij->i", move, normal)[:, None] * normal
        x = project_onto_surface(x + move, sdf, step)
    return x


def triangle_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) interior angles in degrees."""
    v = vertices[faces]
    angles = []
    for i in range(3):
        a, b = v[:, (i + 1) % 3] - v[:, i], v[:, (i + 2) % 3] - v[:, i]
        cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(angles, 1)
