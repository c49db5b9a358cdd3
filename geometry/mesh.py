"""Triangle-mesh topology and validation shared by every geometry routine.

All functions take plain arrays: `vertices` (V, 3) float and `faces` (F, 3) int with counter-clockwise
orientation (normals point outward / along +y for flat cloth at rest).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Undirected edges (E, 2), each row sorted (low, high), rows sorted lexicographically."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(directed, axis=1), axis=0).astype(np.int64)


def edge_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges (E, 2) and, for each, the faces on either side (E, 2); -1 where the edge is on the boundary.

    Assumes an edge-manifold mesh (at most two faces per edge); `validate_mesh` checks that first.
    """
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = len(faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face_of = np.tile(np.arange(n_faces), 3)
    key = np.sort(directed, axis=1)
    edges, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    sides = np.full((len(edges), 2), -1, dtype=np.int64)
    order = np.argsort(inverse, kind="stable")
    inv_sorted = inverse[order]
    first = np.r_[True, inv_sorted[1:] != inv_sorted[:-1]]
    sides[inv_sorted[first], 0] = face_of[order[first]]
    sides[inv_sorted[~first], 1] = face_of[order[~first]]
    return edges.astype(np.int64), sides


def boundary_vertex_mask(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """True for vertices that lie on a boundary edge."""
    edges, sides = edge_faces(faces)
    mask = np.zeros(n_vertices, dtype=bool)
    mask[edges[sides[:, 1] < 0].ravel()] = True
    return mask


def opposite_vertex(faces: np.ndarray, face: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """For each (face, edge) pair, the vertex of `face` that is not on `edge`."""
    tri = faces[face]
    not_on_edge = (tri != edge[:, :1]) & (tri != edge[:, 1:2])
    return tri[np.arange(len(tri)), np.argmax(not_on_edge, axis=1)]


def bending_pairs(faces: np.ndarray) -> np.ndarray:
    """For each interior edge, the two vertices opposite it (E_int, 2): the ends of a cross-edge bending link."""
    faces = np.asarray(faces, dtype=np.int64)
    edges, sides = edge_faces(faces)
    interior = sides[:, 1] >= 0
    e = edges[interior]
    return np.stack([opposite_vertex(faces, sides[interior, 0], e),
                     opposite_vertex(faces, sides[interior, 1], e)], axis=1)


def validate_mesh(vertices: np.ndarray, faces: np.ndarray) -> None:
    """Raise ValueError naming the first problem that makes a mesh unusable for simulation and operators.

    Checks: shapes, finite coordinates, face indices in range, no repeated vertex in a face, no vertex unused,
    at most two faces per edge (edge-manifold), consistent orientation (each directed edge used once), no
    zero-area face, and vertex-manifoldness (the faces around each vertex form a single fan).
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must have shape (F, 3) with F > 0, got {faces.shape}")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise ValueError(f"vertex {int(np.argmax(bad))} has a NaN or infinite coordinate ({int(bad.sum())} such)")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integers, got {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"face indices must lie in [0, {len(vertices)}), found {faces.min()}..{faces.max()}")
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    if repeated.any():
        raise ValueError(f"face {int(np.argmax(repeated))} repeats a vertex")
    unused = np.setdiff1d(np.arange(len(vertices)), faces.ravel())
    if len(unused):
        raise ValueError(f"vertex {int(unused[0])} belongs to no face ({len(unused)} such)")
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    _, counts = np.unique(directed, axis=0, return_counts=True)
    if (counts > 1).any():
        undirected, ucounts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
        if (ucounts > 2).any():
            a, b = undirected[np.argmax(ucounts > 2)]
            raise ValueError(f"non-manifold mesh: edge ({a}, {b}) is shared by more than two faces")
        raise ValueError("faces are not consistently oriented (a directed edge is used twice)")
    v = vertices[faces]
    area2 = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-30)
    flat = area2 <= 1e-14 * scale * scale
    if flat.any():
        raise ValueError(f"face {int(np.argmax(flat))} has zero area")
    _check_vertex_fans(len(vertices), faces)


def _check_vertex_fans(n_vertices: int, faces: np.ndarray) -> None:
    """Each vertex's incident faces must form one fan, connected through the edges around it.

    Nodes are face corners (vertex, face); two corners of one vertex are joined when their faces share an edge
    through that vertex. A manifold mesh has exactly one connected group of corners per vertex.
    """
    edges, sides = edge_faces(faces)
    interior = sides[:, 1] >= 0
    e, f = edges[interior], sides[interior]
    links = []
    for end in (0, 1):
        v = e[:, end]
        corner = [3 * f[:, s] + np.argmax(faces[f[:, s]] == v[:, None], axis=1) for s in (0, 1)]
        links.append(np.stack(corner, axis=1))
    links = np.concatenate(links)
    n_corners = 3 * len(faces)
    graph = scipy.sparse.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n_corners, n_corners))
    _, label = scipy.sparse.csgraph.connected_components(graph, directed=False)
    groups = np.unique(np.stack([faces.ravel(), label], axis=1), axis=0)
    fans = np.bincount(groups[:, 0], minlength=n_vertices)
    bad = fans > 1
    if bad.any():
        raise ValueError(f"non-manifold mesh: several surface sheets meet at vertex {int(np.argmax(bad))}")
