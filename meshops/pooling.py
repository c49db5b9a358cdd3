"""One level of the pooling hierarchy (paper 3.2): a pass of independent edge collapses.

Edges are ranked by the Garland-Heckbert quadric error of moving both ends to the midpoint; the cheapest valid
edge is collapsed and every edge touching its ends is barred for the rest of the pass, so the collapses of a pass
are vertex-disjoint and could run in parallel. Each collapse is checked against the mesh as already changed by
the earlier collapses of the pass (two disjoint collapses can together pinch a valence-4 vertex or fold a face
that each alone would not), which keeps every coarse mesh manifold with the same boundary loops.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from meshops.neighbourhood import QUANTUM, quantise
from meshops.rings import mean_edge_length
from geometry.mesh import edge_faces, opposite_vertex, validate_mesh

# A collapse is refused if it leaves any face's normal more than ~84 degrees from where it was at the start of the
# pass (a flip or near-flip)...
MIN_NORMAL_COSINE = 0.1
# ...or leaves a face with shape quality 4*sqrt(3)*area/sum(edge^2) (1 = equilateral) below this, unless the
# face was already that poor: slivers would spoil the next level's normals, rings and ellipses.
MIN_FACE_QUALITY = 0.1
# The pass stops early once below this fraction of its starting vertices and the errors pass the threshold.
STOP_FRACTION = 0.6


@dataclass(frozen=True)
class Coarsening:
    vertices: np.ndarray   # (Vc, 3) coarse positions: midpoints of merged pairs, copies of the others
    faces: np.ndarray      # (Fc, 3) the fine faces that survive, renumbered, orientation kept
    pool: np.ndarray       # (Vc, 2) the one or two fine vertices of each coarse vertex (equal when one)
    unpool: np.ndarray     # (Vf,) the coarse vertex of each fine vertex
    collapsed: int
    largest_error: float   # largest quadric error collapsed, in squared mean edge lengths


def quadric_errors(vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """Quadric error (E,) of placing each edge's merged vertex at its midpoint (Garland & Heckbert 1997).

    Each vertex sums the plane quadrics of its faces; boundary edges add the plane through the edge
    perpendicular to its face, so that collapses keep the outline of open surfaces.
    """
    p = vertices[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    boundary = sides[:, 1] < 0
    fence = np.cross(vertices[edges[boundary, 1]] - vertices[edges[boundary, 0]], normal[sides[boundary, 0]])
    fence /= np.linalg.norm(fence, axis=1, keepdims=True)
    vertex_quadric = (_sum_plane_quadrics(len(vertices), faces, normal, p[:, 0])
                      + _sum_plane_quadrics(len(vertices), edges[boundary], fence, vertices[edges[boundary, 0]]))
    midpoint = np.c_[(vertices[edges[:, 0]] + vertices[edges[:, 1]]) / 2, np.ones(len(edges))]
    q = vertex_quadric[edges[:, 0]] + vertex_quadric[edges[:, 1]]
    return np.maximum(np.einsum("ei,eij,ej->e", midpoint, q, midpoint), 0.0)


def _sum_plane_quadrics(n_vertices: int, owners: np.ndarray, normal: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Sum over planes (unit `normal` through `point`) of their quadrics, onto each plane's owner vertices."""
    plane = np.c_[normal, -np.einsum("pd,pd->p", normal, point)]
    quadric = np.einsum("pi,pj->pij", plane, plane).reshape(len(plane), 16)
    plane_index = np.repeat(np.arange(len(owners)), owners.shape[1])
    incidence = sp.csr_matrix((np.ones(owners.size), (owners.ravel(), plane_index)), shape=(n_vertices, len(owners)))
    return (incidence @ quadric).reshape(-1, 4, 4)


def collapse_pass(vertices: np.ndarray, faces: np.ndarray, quadric_threshold: float) -> Coarsening:
    """Coarsen a validated manifold mesh by one pass of independent midpoint edge collapses.

    `quadric_threshold` is in squared mean edge lengths: the pass stops at the first edge above it once fewer
    than STOP_FRACTION of the vertices remain, and otherwise when no edge can be collapsed.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(vertices)
    edges, sides = edge_faces(faces)
    scale = mean_edge_length(vertices, edges)
    # Centred first: plane offsets stay small, so flat regions come out at zero error wherever the mesh sits.
    error = quantise(quadric_errors(vertices - vertices.mean(axis=0), faces, edges, sides) / scale ** 2)
    length = np.linalg.norm(vertices[edges[:, 1]] - vertices[edges[:, 0]], axis=1) / scale
    # Flat regions tie at zero error. Among ties, edges between low-valence vertices go first: those vertices
    # have the fewest chances to be paired once their neighbours are taken (the Karp-Sipser idea), which keeps
    # the pass near half the vertices; then shorter edges, which keeps the coarse triangles even.
    valence = np.bincount(edges.ravel(), minlength=n)
    valence_sum = valence[edges[:, 0]] + valence[edges[:, 1]]
    order = np.lexsort((np.arange(len(edges)), quantise(length), valence_sum, error))
    boundary_edge = sides[:, 1] < 0
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[edges[boundary_edge].ravel()] = True
    # The link condition with a virtual vertex joined to the whole boundary: an interior edge between two
    # boundary vertices would pinch the surface (or merge two boundary loops).
    allowed = boundary_edge | ~(on_boundary[edges[:, 0]] & on_boundary[edges[:, 1]])
    opposite = np.full((len(edges), 2), -1, dtype=np.int64)
    for side in (0, 1):
        has = sides[:, side] >= 0
        opposite[has, side] = opposite_vertex(faces, sides[has, side], edges[has])

    state = _PassState(vertices, faces, edges)
    largest = 0.0
    candidates = order[allowed[order]]
    threshold = quantise(quadric_threshold)
    for cost, (c, d), across in zip(error[candidates].tolist(), edges[candidates].tolist(),
                                    opposite[candidates].tolist()):
        if cost > threshold and state.remaining < STOP_FRACTION * n:
            break
        if not (state.locked[c] or state.locked[d]) and state.try_collapse(c, d, across):
            largest = max(largest, cost)
    return state.coarsening(largest * QUANTUM)


class _PassState:
    """The mesh of one pass as collapses accumulate: merged vertices point at their representative. Faces keep
    the unit normal and shape quality they had at the start of the pass: a face moved by several collapses must
    stay within bounds of its fine-level self, not merely of its previous state."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray):
        n = len(vertices)
        self.faces = faces
        self.face_list = faces.tolist()
        self.position = vertices.copy()
        self.normal, self.quality = _unit_normal_and_quality(vertices[faces])
        self.representative = list(range(n))
        self.partner = np.arange(n)
        self.locked = [False] * n
        self.removed = [False] * len(faces)
        self.remaining = n
        adjacency = sp.csr_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]],
                                                              np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n))
        self.adjacency_ptr, self.adjacency = adjacency.indptr.tolist(), adjacency.indices.tolist()
        incidence = sp.csr_matrix((np.ones(faces.size), (faces.ravel(), np.repeat(np.arange(len(faces)), 3))),
                                  shape=(n, len(faces)))
        self.incidence_ptr, self.incidence = incidence.indptr.tolist(), incidence.indices.tolist()

    def _link(self, v: int, without: int) -> set[int]:
        rep = self.representative
        return {rep[x] for x in self.adjacency[self.adjacency_ptr[v]:self.adjacency_ptr[v + 1]] if x != without}

    def _faces_of(self, v: int) -> list[int]:
        return [f for f in self.incidence[self.incidence_ptr[v]:self.incidence_ptr[v + 1]] if not self.removed[f]]

    def try_collapse(self, c: int, d: int, opposite: list[int]) -> bool:
        """Collapse edge (c, d) into c at the midpoint if the result stays manifold and unfolded."""
        rep = self.representative
        # Link condition in the current mesh: common neighbours of c and d must be the edge's opposite vertices.
        if self._link(c, d) & self._link(d, c) - {rep[x] for x in opposite if x >= 0}:
            return False
        faces_c = self._faces_of(c)
        dying = [f for f in faces_c if d in self.face_list[f]]
        moving = [f for f in faces_c if f not in dying] + [f for f in self._faces_of(d) if f not in dying]
        if not moving:  # an isolated triangle would vanish
            return False
        merged = {frozenset(c if x == d else rep[x] for x in self.face_list[f]) for f in moving}
        if len(merged) < len(moving):
            return False
        midpoint = (self.position[c] + self.position[d]) / 2
        corners = self.faces[moving]
        after = np.where(((corners == c) | (corners == d))[..., None], midpoint, self.position[corners])
        normal, quality = _unit_normal_and_quality(after)
        if (np.einsum("fd,fd->f", normal, self.normal[moving]) < MIN_NORMAL_COSINE).any() or \
                (quality < np.minimum(self.quality[moving], MIN_FACE_QUALITY)).any():
            return False
        self.locked[c] = self.locked[d] = True
        rep[d] = c
        self.partner[c] = d
        self.position[c] = self.position[d] = midpoint
        for f in dying:
            self.removed[f] = True
        self.remaining -= 1
        return True

    def coarsening(self, largest_error: float) -> Coarsening:
        representative = np.asarray(self.representative)
        keep = representative == np.arange(len(representative))
        coarse_id = np.cumsum(keep) - 1
        unpool = coarse_id[representative]
        coarse_vertices = self.position[keep]
        coarse_faces = unpool[self.faces[~np.asarray(self.removed)]]
        try:
            validate_mesh(coarse_vertices, coarse_faces)
        except ValueError as err:  # the checks above exist to make this impossible
            raise RuntimeError(f"edge-collapse pass produced an invalid mesh: {err}") from None
        pool = np.stack([np.flatnonzero(keep), self.partner[keep]], axis=1)
        return Coarsening(coarse_vertices, coarse_faces, pool, unpool, int((~keep).sum()), largest_error)


def _unit_normal_and_quality(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (F, 3) and shape quality 4*sqrt(3)*area/sum(edge^2) of triangles (F, 3, 3); a degenerate
    triangle gets quality 0 and a zero normal."""
    u = triangles[:, 1] - triangles[:, 0]
    v = triangles[:, 2] - triangles[:, 0]
    w = triangles[:, 2] - triangles[:, 1]
    normal = np.stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1], u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                       u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]], axis=1)
    doubled_area = np.sqrt(np.einsum("fd,fd->f", normal, normal))
    squares = np.einsum("fd,fd->f", u, u) + np.einsum("fd,fd->f", v, v) + np.einsum("fd,fd->f", w, w)
    return normal / np.maximum(doubled_area, np.finfo(float).tiny)[:, None], 2 * np.sqrt(3) * doubled_area / squares
