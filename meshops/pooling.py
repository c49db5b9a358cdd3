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

from meshops.neighbourhood import quantise
from meshops.rings import mean_edge_length
from sim.mesh import edge_faces, opposite_vertex, validate_mesh

# A collapse is refused if it turns any surviving face's normal by more than ~84 degrees (a flip or near-flip)...
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
    scale = mean_edge_length(vertices, faces)
    edges, sides = edge_faces(faces)
    # Centred first: plane offsets stay small, so flat regions come out at zero error wherever the mesh sits.
    error = quadric_errors(vertices - vertices.mean(axis=0), faces, edges, sides) / scale ** 2
    length = np.linalg.norm(vertices[edges[:, 1]] - vertices[edges[:, 0]], axis=1) / scale
    # Flat regions tie at zero error; shorter edges first keeps the coarse triangles even.
    order = np.lexsort((np.arange(len(edges)), quantise(length), quantise(error)))
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
    for cost, (c, d), across in zip(error[candidates].tolist(), edges[candidates].tolist(),
                                    opposite[candidates].tolist()):
        if cost > quadric_threshold and state.remaining < STOP_FRACTION * n:
            break
        if not (state.locked[c] or state.locked[d]) and state.try_collapse(c, d, across):
            largest = max(largest, cost)
    return state.coarsening(largest)


class _PassState:
    """The mesh of one pass as collapses accumulate: merged vertices point at their representative."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray):
        n = len(vertices)
        self.faces = faces
        self.face_list = faces.tolist()
        self.position = vertices.copy()
        self.representative = list(range(n))
        self.partner = np.arange(n)
        self.locked = [False] * n
        self.removed = np.zeros(len(faces), dtype=bool)
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

    def try_collapse(self, c: int, d: int, opposite: list[int]) -> bool:
        """Collapse edge (c, d) into c at the midpoint if the result stays manifold and unfolded."""
        rep = self.representative
        # Link condition in the current mesh: common neighbours of c and d must be the edge's opposite vertices.
        if self._link(c, d) & self._link(d, c) - {rep[x] for x in opposite if x >= 0}:
            return False
        around = {f for v in (c, d) for f in self.incidence[self.incidence_ptr[v]:self.incidence_ptr[v + 1]]
                  if not self.removed[f]}
        dying = [f for f in around if c in self.face_list[f] and d in self.face_list[f]]
        moving = np.fromiter((f for f in around if f not in dying), dtype=np.int64)
        if not len(moving):  # an isolated triangle would vanish
            return False
        merged = [frozenset(c if x == d else rep[x] for x in self.face_list[f]) for f in moving]
        if len(set(merged)) < len(merged):
            return False
        midpoint = (self.position[c] + self.position[d]) / 2
        before = self.position[self.faces[moving]]
        after = np.where(np.isin(self.faces[moving], (c, d))[..., None], midpoint, before)
        normal_before, quality_before = _normal_and_quality(before)
        normal_after, quality_after = _normal_and_quality(after)
        cosine = np.einsum("fd,fd->f", normal_before, normal_after) / np.maximum(
            np.linalg.norm(normal_before, axis=1) * np.linalg.norm(normal_after, axis=1), np.finfo(float).tiny)
        if np.any(cosine < MIN_NORMAL_COSINE) or np.any(quality_after < np.minimum(quality_before, MIN_FACE_QUALITY)):
            return False
        self.locked[c] = self.locked[d] = True
        rep[d] = c
        self.partner[c] = d
        self.position[c] = self.position[d] = midpoint
        self.removed[dying] = True
        self.remaining -= 1
        return True

    def coarsening(self, largest_error: float) -> Coarsening:
        representative = np.asarray(self.representative)
        keep = representative == np.arange(len(representative))
        coarse_id = np.cumsum(keep) - 1
        unpool = coarse_id[representative]
        coarse_vertices = self.position[keep]
        coarse_faces = unpool[self.faces[~self.removed]]
        try:
            validate_mesh(coarse_vertices, coarse_faces)
        except ValueError as err:  # the checks above exist to make this impossible
            raise RuntimeError(f"edge-collapse pass produced an invalid mesh: {err}") from None
        pool = np.stack([np.flatnonzero(keep), self.partner[keep]], axis=1)
        return Coarsening(coarse_vertices, coarse_faces, pool, unpool, int((~keep).sum()), largest_error)


def _normal_and_quality(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Doubled-area normals (F, 3) and shape quality 4*sqrt(3)*area/sum(edge^2) of triangles (F, 3, 3)."""
    edge = np.roll(triangles, -1, axis=1) - triangles
    normal = np.cross(edge[:, 0], -edge[:, 2])
    return normal, 2 * np.sqrt(3) * np.linalg.norm(normal, axis=1) / np.einsum("fkd,fkd->f", edge, edge)

