"""Tiny, valid mesh hierarchies built here (not by meshops) so the model tests stand alone.

Levels come from repeated greedy edge matching: each pass pairs the two ends of as many disjoint edges as it can,
collapses them, and keeps the rest as singletons. Conv rows are the vertex, then its one-ring neighbours in id
order, then 0 padding (a boundary-like slot) when the ring is shorter than L - 1.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from model.features import Subdivider
from model.mesh_hierarchy import MeshHierarchy, mesh_hierarchy
from geometry.mesh import unique_edges


def grid_mesh(n_rows: int, n_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat rectangle of (n_rows x n_cols) vertices in the xz plane, CCW faces seen from +y."""
    r, c = np.meshgrid(np.arange(n_rows), np.arange(n_cols), indexing="ij")
    vertices = np.stack([c.ravel(), np.zeros(r.size), r.ravel()], axis=1) / max(n_rows, n_cols)
    idx = np.arange(n_rows * n_cols).reshape(n_rows, n_cols)
    a, b, d, e = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])
    return vertices, faces


def one_ring_table(n_vertices: int, edges: np.ndarray, size: int) -> np.ndarray:
    table = np.zeros((n_vertices, size), dtype=np.int64)
    table[:, 0] = np.arange(1, n_vertices + 1)
    neighbours = [[] for _ in range(n_vertices)]
    for a, b in edges:
        neighbours[a].append(b)
        neighbours[b].append(a)
    for v, ring in enumerate(neighbours):
        ring = sorted(ring)[:size - 1]
        table[v, 1:1 + len(ring)] = np.asarray(ring, dtype=np.int64) + 1
    return table


def greedy_pooling(n_vertices: int, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair disjoint edges greedily; returns pool (V_c, 2), unpool (V,), coarse edges."""
    matched = np.full(n_vertices, -1)
    for a, b in edges:
        if matched[a] < 0 and matched[b] < 0:
            matched[a], matched[b] = b, a
    first = np.flatnonzero((matched < 0) | (np.arange(n_vertices) < matched))     # singletons and pair heads
    pool = np.stack([first, np.where(matched[first] < 0, first, matched[first])], axis=1)
    unpool = np.empty(n_vertices, dtype=np.int64)
    unpool[pool[:, 0]] = np.arange(len(pool))
    unpool[pool[:, 1]] = np.arange(len(pool))
    coarse = np.unique(np.sort(unpool[edges], axis=1), axis=0)
    return pool, unpool, coarse[coarse[:, 0] != coarse[:, 1]]


def build_hierarchy(faces: np.ndarray, n_vertices: int, size: int, n_levels: int) -> MeshHierarchy:
    edges = unique_edges(faces)
    conv, pool, unpool = [one_ring_table(n_vertices, edges, size)], [], []
    for _ in range(n_levels - 1):
        p, u, edges = greedy_pooling(n_vertices, edges)
        n_vertices = len(p)
        pool.append(p)
        unpool.append(u)
        conv.append(one_ring_table(n_vertices, edges, size))
    return mesh_hierarchy(conv, pool, unpool)


def identity_subdivider(n_vertices: int, device="cpu") -> Subdivider:
    """S = I: a FrameStore whose S x_low is the positions given (the model tests' frames are on one mesh)."""
    S = sp.identity(n_vertices, format="csr")
    return Subdivider(S.indptr, S.indices, S.data, device)
