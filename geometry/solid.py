"""A closed triangle mesh as a solid: which points lie inside it, and how far points are from its surface.

Inside: a ray from each point down along -z crosses the surface an odd number of times. Counted naively, a ray
through an edge or a vertex of the mesh's projection onto the xy plane meets the two triangles of the edge (or the
fan of the vertex) twice or not at all, and a structured grid's rays pass through vertices and edges whenever the
mesh has vertices on the grid's lines (an axis-aligned box, a mesh made on the same grid). So each edge is tested
with its end points in one global order (by x, then y), and a point on an edge belongs to the triangle lying to
the left of the edge so directed (the top-left rule of rasterisers): of two triangles projecting to both sides of
the edge exactly one has the point, and at a vertex exactly one triangle of a fan that surrounds it, since the
edges directed outwards form one arc of the fan's directions. Where the surface folds over in projection (its
silhouette), a ray on the fold meets both sheets or neither, which keeps the parity.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

_EDGES = ((0, 1), (1, 2), (2, 0))
MAX_BUCKETS = 1024


def inside_mesh(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies inside the closed, consistently oriented mesh (a point on the surface may fall
    either way)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    points = np.asarray(points, dtype=np.float64)
    columns, column_of = np.unique(points[:, :2], axis=0, return_inverse=True)
    pair_tri, pair_col = _candidate_pairs(tri[:, :, :2], columns)
    hit, height = _crossings(tri[pair_tri], columns[pair_col])
    crossing_col, crossing_z = pair_col[hit], height[hit]
    # Crossings and points sorted together by column, then height: the crossings before a point in that order,
    # less those of earlier columns, are the ones below it in its column.
    col = np.concatenate([crossing_col, column_of])
    z = np.concatenate([crossing_z, points[:, 2]])
    is_point = np.concatenate([np.zeros(len(crossing_col), bool), np.ones(len(points), bool)])
    order = np.lexsort((is_point, z, col))
    crossings_before = np.cumsum(~is_point[order]) - ~is_point[order]
    below = np.empty(len(points), np.int64)
    below[order[is_point[order]] - len(crossing_col)] = crossings_before[is_point[order]]
    below -= np.searchsorted(np.sort(crossing_col), column_of)
    return below % 2 == 1


def _candidate_pairs(tri2: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(triangle, column) pairs whose column may pass through the triangle's projection: columns bucketed on a
    square grid about one triangle across, each triangle paired with the columns of the buckets its box covers."""
    lo, hi = tri2.min(axis=1), tri2.max(axis=1)
    # At most MAX_BUCKETS buckets a side: a few tiny triangles far apart would otherwise ask for billions.
    cell = max(float(np.mean(hi - lo)), float(np.ptp(columns, axis=0).max()) / MAX_BUCKETS,
               1e-12 * (1.0 + float(np.abs(columns).max())))
    origin = columns.min(axis=0)
    n_cells = np.floor((columns.max(axis=0) - origin) / cell).astype(np.int64) + 1
    bucket = np.floor((columns - origin) / cell).astype(np.int64)
    key = bucket[:, 0] * n_cells[1] + bucket[:, 1]
    by_key = np.argsort(key, kind="stable")
    first = np.searchsorted(key[by_key], np.arange(n_cells.prod() + 1))
    b0 = np.clip(np.floor((lo - origin) / cell).astype(np.int64), 0, n_cells - 1)
    b1 = np.clip(np.floor((hi - origin) / cell).astype(np.int64), 0, n_cells - 1)
    seen = (hi >= origin).all(axis=1) & (lo <= columns.max(axis=0)).all(axis=1)
    span = np.where(seen[:, None], b1 - b0 + 1, 0)
    # Every (triangle, bucket) pair, then every column of the bucket.
    t = np.repeat(np.arange(len(tri2)), span.prod(axis=1))
    k = np.arange(len(t)) - np.repeat(np.cumsum(span.prod(axis=1)) - span.prod(axis=1), span.prod(axis=1))
    cells = (b0[t, 0] + k // span[t, 1]) * n_cells[1] + b0[t, 1] + k % span[t, 1]
    counts = first[cells + 1] - first[cells]
    pair_tri = np.repeat(t, counts)
    offset = np.arange(len(pair_tri)) - np.repeat(np.cumsum(counts) - counts, counts)
    return pair_tri, by_key[np.repeat(first[cells], counts) + offset]


def _crossings(tri: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether each vertical line through q (n, 2) meets its triangle (n, 3, 3) under the top-left rule, and the
    height where it does."""
    hit = np.ones(len(q), dtype=bool)
    for i, j in _EDGES:
        a, b, other = tri[:, i, :2], tri[:, j, :2], tri[:, 3 - i - j, :2]
        swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
        p, r = np.where(swap[:, None], b, a), np.where(swap[:, None], a, b)
        # The same end points in the same order for both triangles of the edge: the same bits of w in both.
        w = (r[:, 0] - p[:, 0]) * (q[:, 1] - p[:, 1]) - (r[:, 1] - p[:, 1]) * (q[:, 0] - p[:, 0])
        side = (r[:, 0] - p[:, 0]) * (other[:, 1] - p[:, 1]) - (r[:, 1] - p[:, 1]) * (other[:, 0] - p[:, 0])
        hit &= (w * side > 0) | ((w == 0) & (side > 0))
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    hit &= normal[:, 2] != 0            # a triangle seen edge-on: its neighbours count the crossing
    nz = np.where(hit, normal[:, 2], 1.0)
    height = tri[:, 0, 2] - (normal[:, 0] * (q[:, 0] - tri[:, 0, 0]) + normal[:, 1] * (q[:, 1] - tri[:, 0, 1])) / nz
    return hit, height


def distance_to_mesh(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) the distance from each point to the mesh's surface. Only triangles whose bounding box is within the
    point's distance to its nearest vertex (a bound on the answer) are measured."""
    import trimesh  # imported here: only a user's hand needs it, and it is slow to import

    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces)
    points = np.asarray(points, dtype=np.float64)
    bound = cKDTree(vertices[np.unique(faces)]).query(points)[0]
    tri = vertices[faces]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    out = np.empty(len(points))
    for k, (p, d) in enumerate(zip(points, bound)):
        near = np.flatnonzero((np.maximum(lo - p, 0) + np.maximum(p - hi, 0)).max(axis=1) <= d)
        closest = trimesh.triangles.closest_point(tri[near], np.broadcast_to(p, (len(near), 3)))
        out[k] = np.linalg.norm(closest - p, axis=1).min()
    return out
