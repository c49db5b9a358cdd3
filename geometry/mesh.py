"""Triangle-mesh topology and validation shared by every geometry routine, and the two seam operations: cutting a
mesh open along edges into panels, and welding duplicated seam vertices back together.

All functions take plain arrays: `vertices` (V, 3) float and `faces` (F, 3) int with counter-clockwise
orientation (normals point outward / along +y for flat cloth at rest).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.spatial


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
    """Each vertex's incident faces must form one fan, connected through the edges around it."""
    edges, sides = edge_faces(faces)
    label = _corner_fans(faces, edges, sides, sides[:, 1] >= 0)
    groups = np.unique(np.stack([faces.ravel(), label], axis=1), axis=0)
    fans = np.bincount(groups[:, 0], minlength=n_vertices)
    bad = fans > 1
    if bad.any():
        raise ValueError(f"non-manifold mesh: several surface sheets meet at vertex {int(np.argmax(bad))}")


def _corner_fans(faces: np.ndarray, edges: np.ndarray, sides: np.ndarray, joined: np.ndarray) -> np.ndarray:
    """Label (3F,) of each face corner (vertex, face), numbered 3 * face + corner: two corners of one vertex share
    a label when their faces are linked, through that vertex, by a chain of `joined` edges (a mask over `edges`,
    interior edges only). A manifold mesh with every interior edge joined has one label per vertex."""
    e, f = edges[joined], sides[joined]
    links = []
    for end in (0, 1):
        v = e[:, end]
        corner = [3 * f[:, s] + np.argmax(faces[f[:, s]] == v[:, None], axis=1) for s in (0, 1)]
        links.append(np.stack(corner, axis=1))
    links = np.concatenate(links)
    n_corners = 3 * len(faces)
    graph = scipy.sparse.coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n_corners, n_corners))
    return scipy.sparse.csgraph.connected_components(graph, directed=False)[1]


def cut_along_edges(vertices: np.ndarray, faces: np.ndarray, cut: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut a validated manifold mesh open along the edges `cut` (C, 2), as an artist's garment is a set of panels
    whose seam vertices are duplicated: each vertex gets one copy per fan of its faces that stays connected
    across uncut edges (a panel may meet itself along a cut, like a waistband closed by one seam).

    Returns vertices (V', 3), faces (F, 3) in the same order with the same corners, and `new_to_old` (V',).
    The copies of a vertex are consecutive, in the order of the vertices they copy, so `weld_vertices` with a
    tolerance below the shortest edge gives the uncut mesh back exactly. Edges of `cut` that are not interior
    edges of the mesh change nothing.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(vertices)
    edges, sides = edge_faces(faces)
    cut = np.sort(np.asarray(cut, dtype=np.int64).reshape(-1, 2), axis=1)
    joined = (sides[:, 1] >= 0) & ~np.isin(edges[:, 0] * n + edges[:, 1], cut[:, 0] * n + cut[:, 1])
    label = _corner_fans(faces, edges, sides, joined)
    _, first_corner, corner_copy = np.unique(label, return_index=True, return_inverse=True)
    old = faces.ravel()[first_corner]
    order = np.lexsort((first_corner, old))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return vertices[old[order]], rank[corner_copy.ravel()].reshape(faces.shape), old[order]


def weld_vertices(vertices: np.ndarray, faces: np.ndarray, tolerance: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge vertices closer than `tolerance` (inclusive; chains merge whole, single linkage), as seams are sewn
    shut: each group becomes its lowest-numbered vertex, at that vertex's position, and the merged vertices keep
    the order of their first occurrence. Faces that lose a corner to the merge (slivers shorter than the
    tolerance) are dropped; the others keep their order.

    Returns vertices (V', 3), faces (F', 3) and `old_to_new` (V,). Tolerance 0 merges exact duplicates only.
    Deterministic: the groups depend only on pairwise distances, not on the order a search finds them in.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"weld tolerance must be finite and >= 0, got {tolerance}")
    n = len(vertices)
    pairs = scipy.spatial.cKDTree(vertices).query_pairs(tolerance, output_type="ndarray")
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = scipy.sparse.csgraph.connected_components(graph, directed=False)
    # Groups ranked by their lowest vertex, whatever numbering connected_components gives them.
    first = np.full(group.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, group, np.arange(n))
    rank = np.argsort(np.argsort(first))
    old_to_new = rank[group]
    welded = old_to_new[faces]
    kept = (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 2] != welded[:, 0])
    return vertices[np.sort(first)], welded[kept], old_to_new


def boundary_loops(n_vertices: int, faces: np.ndarray) -> list[np.ndarray]:
    """The boundary loops of a validated manifold mesh, each the vertex ids (k,) in the order of their faces' edges
    (the mesh lies to the left of the walk), longest loop first. A vertex-manifold mesh has one boundary edge
    leaving each boundary vertex, so every walk closes on its start."""
    faces = np.asarray(faces, dtype=np.int64)
    tail, head = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    unpaired = ~np.isin(tail * n_vertices + head, head * n_vertices + tail)
    following = np.full(n_vertices, -1, dtype=np.int64)
    following[tail[unpaired]] = head[unpaired]
    seen = np.zeros(n_vertices, dtype=bool)
    loops = []
    for start in tail[unpaired]:
        if seen[start]:
            continue
        loop = [start]
        seen[start] = True
        while not seen[following[loop[-1]]]:
            loop.append(following[loop[-1]])
            seen[loop[-1]] = True
        loops.append(np.asarray(loop, dtype=np.int64))
    return sorted(loops, key=len, reverse=True)
