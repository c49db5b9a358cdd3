"""The fixed vertex (paper eq. 2) and geodesic distances from it, which orient every convolution filter.

Distances come from the heat method (Crane, Weischedel & Wardetzky 2013): unlike edge-graph Dijkstra, whose
metric follows the edges and ties constantly on regular grids, it approximates the smooth geodesic distance, so
"the neighbour geodesically closest to the fixed vertex" points the same way across a mesh. One implicit heat
step decays like exp(-d / sqrt(t)); on meshes more than ~700 edge lengths across it underflows, and the
distances then come from Dijkstra on the edge graph instead (reported as the method used).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla


def fixed_vertex(vertices: np.ndarray) -> int:
    """Vertex closest to ((max_x + min_x) / 2, max_y, (max_z + min_z) / 2) of the bounding box, y up (eq. 2).

    Symmetric meshes tie (two vertices either side of the middle); ties go to the lowest vertex id.
    """
    return int(np.argmin(_distance_to_top_centre(vertices)))


def _distance_to_top_centre(vertices: np.ndarray) -> np.ndarray:
    """Distances to the eq. 2 point, rounded to 1e-9 of the bounding-box diagonal so that exact ties stay ties
    however the mesh is translated or scaled."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    centre = np.array([(low[0] + high[0]) / 2, high[1], (low[2] + high[2]) / 2])
    diagonal = max(float(np.linalg.norm(high - low)), np.finfo(float).tiny)
    return np.rint(np.linalg.norm(vertices - centre, axis=1) / diagonal * 1e9)


def geodesic_sources(vertices: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """One source per connected component: the fixed vertex first, then, for every other component (a mesh may
    hold separate pieces), its vertex closest to the same eq. 2 point, so each piece has a reachable origin.
    `edges` (E, 2) lists each undirected edge once."""
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, component = csgraph.connected_components(graph, directed=False)
    distance = _distance_to_top_centre(vertices)
    order = np.lexsort((distance, component))
    first_of_component = order[np.r_[True, np.diff(component[order]) != 0]]
    fixed = fixed_vertex(vertices)
    return np.r_[fixed, first_of_component[first_of_component != fixed]].astype(np.int64)


def geodesic_distance(vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray,
                      sources: np.ndarray) -> tuple[np.ndarray, str]:
    """Distance (V,) from the nearest source along the surface, and the method that produced it."""
    distance = heat_geodesic_distance(vertices, faces, edges, sources)
    if distance is not None:
        return distance, "heat"
    return graph_geodesic_distance(vertices, edges, sources), "dijkstra"


def heat_geodesic_distance(vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray,
                           sources: np.ndarray) -> np.ndarray | None:
    """Heat-method distance with natural (Neumann) boundary conditions and t = (mean edge length)^2.

    Returns None when the heat step underflowed somewhere (zero gradient), where directions carry no information.
    """
    gradient, face_area = _gradient_operator(vertices, faces)
    weight = sp.diags(np.repeat(face_area, 3))
    stiffness = (gradient.T @ weight @ gradient).tocsc()
    mass = np.bincount(faces.ravel(), weights=np.repeat(face_area / 3, 3), minlength=len(vertices))
    t = float(np.mean(np.sum((vertices[edges[:, 0]] - vertices[edges[:, 1]]) ** 2, axis=1)))

    impulse = np.zeros(len(vertices))
    impulse[sources] = 1.0
    heat = spla.splu((sp.diags(mass) + t * stiffness).tocsc()).solve(impulse)
    flow = (gradient @ heat).reshape(-1, 3)
    flow_norm = np.linalg.norm(flow, axis=1)
    if not (np.all(np.isfinite(heat)) and np.all(heat > 0) and np.all(flow_norm > np.finfo(float).tiny)):
        return None
    direction = -(flow / flow_norm[:, None]).ravel()

    # Poisson step: the distance whose gradient best matches the unit field, pinned to 0 at every source.
    divergence = gradient.T @ (np.repeat(face_area, 3) * direction)
    free = np.ones(len(vertices), dtype=bool)
    free[sources] = False
    distance = np.zeros(len(vertices))
    distance[free] = spla.splu(stiffness[free][:, free].tocsc()).solve(divergence[free])
    return distance


def graph_geodesic_distance(vertices: np.ndarray, edges: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Shortest path along mesh edges (Dijkstra) from the nearest source."""
    n = len(vertices)
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    return csgraph.dijkstra(graph, directed=False, indices=sources, min_only=True)


def _gradient_operator(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Per-face gradient of a piecewise-linear function, as a (3F, V) matrix, and the face areas.

    On a face with unit normal N and area A the gradient is sum_i u_i (N x e_i) / (2A), e_i the edge opposite
    corner i taken counter-clockwise.
    """
    p = vertices[faces]
    doubled_normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    doubled_area = np.linalg.norm(doubled_normal, axis=1)
    unit_normal = doubled_normal / doubled_area[:, None]
    rows, cols, vals = [], [], []
    n_faces = len(faces)
    for corner in range(3):
        opposite_edge = p[:, (corner + 2) % 3] - p[:, (corner + 1) % 3]
        value = np.cross(unit_normal, opposite_edge) / doubled_area[:, None]
        for axis in range(3):
            rows.append(3 * np.arange(n_faces) + axis)
            cols.append(faces[:, corner])
            vals.append(value[:, axis])
    gradient = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * n_faces, len(vertices))).tocsr()
    return gradient, doubled_area / 2
