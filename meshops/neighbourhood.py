"""Everything the convolution tables of one mesh level share: oriented one-rings, k-ring distances, tangent
frames and the dummy vertices that stand for the missing side of rings cut by a boundary (paper 3.1, Fig. 3).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshops.geodesic import geodesic_distance, geodesic_sources
from meshops.rings import (boundary_walk, mean_edge_length, ordered_one_ring, pair_lookup, ring_distances,
                           vertex_normals)
from geometry.mesh import unique_edges

DUMMY = -2  # marks the one-ring dummy inside `Neighbourhood.ring`; -1 is padding
# Geometric keys (distances, angles) are rounded to this fraction of the mean edge length (or radian) before
# they decide an order, so that exact ties stay ties under translation and scaling and break the same way.
QUANTUM = 1e-6
# The paper's assignment candidates: the one-, two- and three-ring of the vertex (plus dummies).
ASSIGNMENT_RINGS = 3
# An offset whose projection onto a vertex's tangent plane is shorter than this fraction of the lengths at hand
# points nowhere in that plane: a seam copy of the vertex itself (a panel meeting itself along a seam within three
# rings: near the end of a dart, or a cuff closed by one seam once pooling has shrunk it), or a neighbour on the
# normal line of a sharply folded vertex.
NO_DIRECTION = 1e-9


def quantise(value: np.ndarray) -> np.ndarray:
    """`value` (already in mean edge lengths or radians) as an integer count of QUANTUM, in float64."""
    return np.rint(value / QUANTUM)


@dataclass(frozen=True)
class Neighbourhood:
    vertices: np.ndarray        # (V, 3) float64
    scale: float                # mean edge length
    normal: np.ndarray          # (V, 3) unit vertex normals
    tangent: np.ndarray         # (V, 3) unit, towards the first neighbour in the tangent plane
    bitangent: np.ndarray       # (V, 3) normal x tangent: a quarter turn counter-clockwise from `tangent`
    ring: np.ndarray            # (V, K) closed one-ring, counter-clockwise from the first neighbour; DUMMY, -1 pad
    ring_count: np.ndarray      # (V,) entries of `ring` (valence, plus one on the boundary)
    ring_dummy: np.ndarray      # (V, 3) position of the one-ring dummy (boundary vertices only)
    indptr: np.ndarray          # CSR over vertices of the k-ring neighbourhood, itself included
    neighbour: np.ndarray
    distance: np.ndarray        # edge-graph distance of each neighbour (0 = the vertex itself)
    dummy_owner: np.ndarray     # (D,) vertex whose k-ring a dummy completes
    dummy_ring: np.ndarray      # (D,) k in 1..3
    dummy_position: np.ndarray  # (D, 3)
    fixed_vertex: int
    geodesic_sources: np.ndarray
    geodesic_method: str

    @property
    def owner(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.vertices)), np.diff(self.indptr))

    def ring_positions(self) -> np.ndarray:
        """(V, K, 3) positions of `ring`, the dummy in its place, padding copied from the first entry."""
        ids = np.where(self.ring >= 0, self.ring, 0)
        points = self.vertices[ids]
        points = np.where((self.ring == DUMMY)[..., None], self.ring_dummy[:, None, :], points)
        return np.where((self.ring == -1)[..., None], points[:, :1], points)

    def tangent_coordinates(self, points: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """2-D coordinates (..., 2) of `points` relative to their owner vertex in its tangent frame."""
        offset = points - self.vertices[owner]
        return np.stack([np.einsum("...d,...d->...", offset, self.tangent[owner]),
                         np.einsum("...d,...d->...", offset, self.bitangent[owner])], axis=-1)


def build_neighbourhood(vertices: np.ndarray, faces: np.ndarray, depth: int = ASSIGNMENT_RINGS) -> Neighbourhood:
    """Neighbourhood data of a validated manifold mesh, k-rings up to `depth` (at least ASSIGNMENT_RINGS)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n = len(vertices)
    edges = unique_edges(faces)
    scale = mean_edge_length(vertices, edges)
    ring, size, is_open = ordered_one_ring(n, faces)
    sources = geodesic_sources(vertices, edges)
    geodesic, method = geodesic_distance(vertices, faces, edges, sources)
    normal = vertex_normals(vertices, faces)
    indptr, neighbour, distance = ring_distances(n, edges, max(depth, ASSIGNMENT_RINGS))
    following, preceding = boundary_walk(n, faces)
    dummy_owner, dummy_ring, dummy_position = ring_dummies(vertices, normal, following, preceding,
                                                           indptr, neighbour, distance)
    ring_dummy = np.zeros_like(vertices)
    one_ring = dummy_ring == 1
    ring_dummy[dummy_owner[one_ring]] = dummy_position[one_ring]

    # Close each ring (the dummy fills a boundary vertex's gap) and rotate it to start at the first neighbour:
    # the real neighbour geodesically closest to the fixed vertex, ties to the earliest in ring order.
    closed = np.concatenate([ring, np.full((n, 1), -1)], axis=1)
    closed[np.arange(n)[is_open], size[is_open]] = DUMMY
    count = size + is_open
    key = np.where(ring >= 0, quantise(geodesic[np.maximum(ring, 0)] / scale), np.inf)
    shift = np.argmin(key, axis=1)
    column = (np.arange(closed.shape[1])[None, :] + shift[:, None]) % count[:, None]
    rotated = np.where(np.arange(closed.shape[1])[None, :] < count[:, None],
                       np.take_along_axis(closed, column, axis=1), -1)

    first = vertices[rotated[:, 0]] - vertices
    tangent, _ = tangent_directions(first, normal, np.linalg.norm(first, axis=1))
    return Neighbourhood(vertices, scale, normal, tangent, np.cross(normal, tangent), rotated, count, ring_dummy,
                         indptr, neighbour, distance, dummy_owner, dummy_ring, dummy_position,
                         int(sources[0]), sources, method)


def ring_dummies(vertices: np.ndarray, normal: np.ndarray, following: np.ndarray, preceding: np.ndarray,
                 indptr: np.ndarray, neighbour: np.ndarray, distance: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One dummy vertex for every place where the k-ring of a vertex (k = 1..3) is cut open by a boundary.

    The disk of vertices closer than k contains runs of boundary vertices; each run, walked along its loop, is
    entered from a k-ring vertex A and left to a k-ring vertex B (the two ends of the open k-ring). The missing
    part of the ring is the counter-clockwise arc from A to B around the vertex normal; the dummy sits midway
    along it in angle and at the mean distance of A and B (paper Fig. 3). A boundary loop lying entirely inside
    the disk does not cut the ring and gets no dummy.
    """
    n = len(vertices)
    owner = np.repeat(np.arange(n), np.diff(indptr))
    find = pair_lookup(indptr, neighbour, n)

    def inside(v: np.ndarray, other: np.ndarray, k: int) -> np.ndarray:
        at = find(v, other)
        return (at >= 0) & (distance[np.maximum(at, 0)] < k)

    owners, rings, ends_a, ends_b = [], [], [], []
    on_boundary = following[neighbour] >= 0
    for k in range(1, ASSIGNMENT_RINGS + 1):
        run_start = on_boundary & (distance < k) & ~inside(owner, preceding[neighbour], k)
        v, last = owner[run_start], neighbour[run_start]
        walking = np.ones(len(v), dtype=bool)
        while walking.any():
            walking[walking] = inside(v[walking], following[last[walking]], k)
            last[walking] = following[last[walking]]
        owners.append(v)
        rings.append(np.full(len(v), k))
        ends_a.append(preceding[neighbour[run_start]])
        ends_b.append(following[last])
    owner_d, ring_d = np.concatenate(owners), np.concatenate(rings)
    a, b = np.concatenate(ends_a), np.concatenate(ends_b)
    return owner_d, ring_d, midway_dummy(vertices[owner_d], normal[owner_d], vertices[a], vertices[b])


def midway_dummy(centre: np.ndarray, normal: np.ndarray, end_a: np.ndarray, end_b: np.ndarray) -> np.ndarray:
    """Point midway, in angle counter-clockwise from A to B around the normal and in distance, between the ends.

    An end with no direction in the tangent plane (a seam copy of the centre, see NO_DIRECTION) is taken to lie
    in the other end's direction, as when A = B: the whole turn is missing and the dummy faces the other end.
    """
    to_a, to_b = end_a - centre, end_b - centre
    distance_a, distance_b = np.linalg.norm(to_a, axis=1), np.linalg.norm(to_b, axis=1)
    reach = np.maximum(distance_a, distance_b)
    unit_a, has_a = tangent_directions(to_a, normal, reach)
    unit_b, has_b = tangent_directions(to_b, normal, reach)
    unit_a = np.where(has_a[:, None], unit_a, unit_b)
    unit_b = np.where(has_b[:, None], unit_b, unit_a)
    angle = np.mod(np.arctan2(np.einsum("nd,nd->n", np.cross(unit_a, unit_b), normal),
                              np.einsum("nd,nd->n", unit_a, unit_b)), 2 * np.pi)
    angle = np.where(angle <= 1e-12, 2 * np.pi, angle)  # A = B: the whole turn is missing
    direction = np.cos(angle / 2)[:, None] * unit_a + np.sin(angle / 2)[:, None] * np.cross(normal, unit_a)
    return centre + ((distance_a + distance_b) / 2)[:, None] * direction


def tangent_directions(offset: np.ndarray, normal: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit projections (N, 3) of `offset` onto the planes perpendicular to the unit `normal`, and a mask (N,) of
    those that exist: longer than NO_DIRECTION * `length`. The others get a fixed unit vector of the plane (along
    the coordinate axis least aligned with the normal), so that every frame stays finite and deterministic."""
    flat = offset - np.einsum("nd,nd->n", offset, normal)[:, None] * normal
    size = np.linalg.norm(flat, axis=1)
    defined = size > NO_DIRECTION * length
    axis = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    fixed = axis - np.einsum("nd,nd->n", axis, normal)[:, None] * normal
    flat = np.where(defined[:, None], flat, fixed)
    return flat / np.linalg.norm(flat, axis=1, keepdims=True), defined
