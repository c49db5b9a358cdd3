"""Loop subdivision as a sparse linear map from coarse to fine vertex positions.

Loop's weights depend only on connectivity, so one level is a matrix S (V+E, V) with fine = S @ coarse for any
per-vertex quantity (positions, velocities, displacements). Even (old) vertices keep their indices 0..V-1, so
pinned coarse vertices map to the same indices on the fine mesh; odd (edge) vertices follow in the order of
`geometry.mesh.unique_edges`.

Boundaries use the true crease rule (boundary curve = cubic B-spline subdivision of the boundary polygon), so the
fine boundary depends only on the coarse boundary vertices.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from geometry.mesh import edge_faces, opposite_vertex, validate_mesh


def loop_beta(valence: np.ndarray) -> np.ndarray:
    """Loop's original neighbour weight β(n) = (5/8 - (3/8 + cos(2π/n)/4)²) / n (trimesh 5.2.0 uses the same)."""
    n = np.asarray(valence, dtype=np.float64)
    return (5.0 / 8.0 - (3.0 / 8.0 + 0.25 * np.cos(2.0 * np.pi / n)) ** 2) / n


def loop_subdivision_matrix(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """One level of Loop subdivision: S (V+E, V) CSR and the new faces (4F, 3) int64.

    Raises ValueError (from `validate_mesh`) if the mesh is not a valid oriented 2-manifold.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    validate_mesh(vertices, faces)
    return _subdivide_topology(len(vertices), faces)


def loop_subdivide(vertices: np.ndarray, faces: np.ndarray, levels: int = 2) -> tuple[sp.csr_matrix, np.ndarray]:
    """`levels` levels of Loop subdivision: S (V_levels, V) CSR, the product of the per-level maps, and the faces."""
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    validate_mesh(vertices, faces)
    # Subdivision of a valid manifold is a valid manifold, so only the input needs validating.
    total = sp.identity(len(vertices), format="csr", dtype=np.float64)
    for _ in range(levels):
        level, faces = _subdivide_topology(total.shape[0], faces)
        total = (level @ total).tocsr()
    total.sort_indices()
    return total, faces


def _subdivide_topology(n_vertices: int, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    edges, sides = edge_faces(faces)
    n_edges = len(edges)
    boundary_edge = sides[:, 1] < 0
    on_boundary = np.zeros(n_vertices, dtype=bool)
    on_boundary[edges[boundary_edge].ravel()] = True
    valence = np.bincount(edges.ravel(), minlength=n_vertices)
    beta = loop_beta(valence)

    # Even rows. Each undirected edge contributes to the rows of both its ends; a boundary vertex only takes its
    # two boundary-edge neighbours (crease rule), never a boundary vertex reached through an interior edge.
    source = np.concatenate([edges[:, 0], edges[:, 1]])
    neighbour = np.concatenate([edges[:, 1], edges[:, 0]])
    along_boundary = np.tile(boundary_edge, 2)
    neighbour_weight = np.where(on_boundary[source], np.where(along_boundary, 1.0 / 8.0, 0.0), beta[source])
    self_weight = np.where(on_boundary, 3.0 / 4.0, 1.0 - valence * beta)

    # Odd rows: 3/8 on the edge ends and 1/8 on the two opposite vertices; the midpoint on a boundary edge.
    odd_row = n_vertices + np.arange(n_edges)
    end_weight = np.where(boundary_edge, 0.5, 3.0 / 8.0)
    interior = ~boundary_edge
    e_int = edges[interior]
    opposite = np.concatenate([opposite_vertex(faces, sides[interior, 0], e_int),
                               opposite_vertex(faces, sides[interior, 1], e_int)])

    rows = np.concatenate([source, np.arange(n_vertices), odd_row, odd_row, np.tile(odd_row[interior], 2)])
    cols = np.concatenate([neighbour, np.arange(n_vertices), edges[:, 0], edges[:, 1], opposite])
    vals = np.concatenate([neighbour_weight, self_weight, end_weight, end_weight,
                           np.full(len(opposite), 1.0 / 8.0)])
    keep = vals != 0.0
    matrix = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n_vertices + n_edges, n_vertices))
    matrix.sort_indices()
    return matrix, _split_faces(n_vertices, faces, edges)


def _split_faces(n_vertices: int, faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Each face (a, b, c) becomes (a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca), keeping its orientation."""
    edge_key = edges[:, 0] * n_vertices + edges[:, 1]  # increasing, since edges are sorted lexicographically
    corner_pairs = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1)  # (F, 3, 2)
    lo, hi = corner_pairs.min(axis=2), corner_pairs.max(axis=2)
    ab, bc, ca = (n_vertices + np.searchsorted(edge_key, lo * n_vertices + hi)).T
    a, b, c = faces.T
    return np.stack([np.stack([a, ab, ca], axis=1), np.stack([ab, b, bc], axis=1),
                     np.stack([ca, bc, c], axis=1), np.stack([ab, bc, ca], axis=1)], axis=1).reshape(-1, 3)
