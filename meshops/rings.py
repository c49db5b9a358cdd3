"""Vertex neighbourhoods of a manifold, consistently oriented triangle mesh, vectorised over vertices.

The one-ring order comes from the face corners: in a counter-clockwise face (c, n, p) the neighbour p follows n
counter-clockwise around c, so chaining corners walks the ring. A boundary vertex's ring is an open chain that
starts at the neighbour no corner leads to.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp



def ordered_one_ring(n_vertices: int, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Counter-clockwise one-ring of every vertex.

    Returns `ring` (V, K) int64 padded with -1, `size` (V,) the valence, and `is_open` (V,) True on the boundary.
    Interior rings start at their smallest neighbour id; boundary rings run from one boundary neighbour to the
    other, so the gap (outside the mesh) lies between the last and the first entry.
    """
    faces = np.asarray(faces, dtype=np.int64)
    centre = faces.ravel()
    following = np.roll(faces, -1, axis=1).ravel()
    preceding = np.roll(faces, 1, axis=1).ravel()
    key = centre * n_vertices + following
    order = np.argsort(key)
    sorted_key, successor = key[order], preceding[order]

    starts_chain = ~np.isin(key, centre * n_vertices + preceding)
    is_open = np.zeros(n_vertices, dtype=bool)
    is_open[centre[starts_chain]] = True
    start = np.empty(n_vertices, dtype=np.int64)
    first_corner = np.r_[True, np.diff(centre[order]) != 0]
    start[centre[order][first_corner]] = following[order][first_corner]
    start[centre[starts_chain]] = following[starts_chain]

    size = np.bincount(centre, minlength=n_vertices) + is_open
    ring = np.full((n_vertices, size.max()), -1, dtype=np.int64)
    ring[:, 0] = start
    vertex = np.arange(n_vertices)
    current = start
    for step in range(1, ring.shape[1]):
        active = step < size
        at = np.searchsorted(sorted_key, vertex[active] * n_vertices + current[active])
        current = current.copy()
        current[active] = successor[at]
        ring[active, step] = current[active]
    return ring, size, is_open


def ring_distances(n_vertices: int, edges: np.ndarray, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge-graph distance from every vertex to every vertex at most `depth` edges away (itself included, at 0).

    Returned as CSR arrays `indptr` (V+1,), `neighbour` (N,), `distance` (N,) with neighbours sorted by id, so
    the pair keys `owner * V + neighbour` are sorted too. `edges` (E, 2) lists each undirected edge once.
    """
    step = sp.coo_matrix((np.ones(2 * len(edges), dtype=np.int32),
                          (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
                         shape=(n_vertices, n_vertices)).tocsr() + sp.identity(n_vertices, dtype=np.int32, format="csr")
    # The reach sets S_0 ⊂ S_1 ⊂ ... are nested, so an entry counted c times lies at distance depth + 1 - c.
    reach = sp.identity(n_vertices, dtype=np.int32, format="csr")
    count = reach.copy()
    for _ in range(depth):
        reach = reach @ step
        reach.data[:] = 1
        count = count + reach
    count.sort_indices()
    return count.indptr.astype(np.int64), count.indices.astype(np.int64), (depth + 1 - count.data).astype(np.int64)


def pair_lookup(indptr: np.ndarray, neighbour: np.ndarray, n_vertices: int):
    """Function mapping (owner, other) arrays to positions in the CSR arrays, -1 where the pair is absent."""
    owner = np.repeat(np.arange(n_vertices), np.diff(indptr))
    keys = owner * n_vertices + neighbour

    def find(v: np.ndarray, other: np.ndarray) -> np.ndarray:
        wanted = v * n_vertices + other
        at = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
        return np.where((keys[at] == wanted) & (other >= 0), at, -1)

    return find


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals (V, 3)."""
    v = vertices[faces]
    face_normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    normals = np.zeros_like(vertices, dtype=np.float64)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normal)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), np.finfo(float).tiny)


def boundary_walk(n_vertices: int, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Next and previous boundary vertex along each boundary loop (-1 off the boundary).

    Loops run in the direction of their faces' edges, so the mesh lies to the left of the walk.
    """
    faces = np.asarray(faces, dtype=np.int64)
    tail = faces.ravel()
    head = np.roll(faces, -1, axis=1).ravel()
    unpaired = ~np.isin(tail * n_vertices + head, head * n_vertices + tail)
    following = np.full(n_vertices, -1, dtype=np.int64)
    preceding = np.full(n_vertices, -1, dtype=np.int64)
    following[tail[unpaired]] = head[unpaired]
    preceding[head[unpaired]] = tail[unpaired]
    return following, preceding


def mean_edge_length(vertices: np.ndarray, edges: np.ndarray) -> float:
    return float(np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).mean())
