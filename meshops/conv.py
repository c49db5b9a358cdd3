"""Convolution index tables (paper 3.1): rows of vertex ids + 1, column 0 the vertex itself, 0 = zero padding.

RC and EC place L-1 uniform samples on a closed curve around the vertex (the one-ring polyline, or the best-fit
ellipse of the one-ring in the tangent plane), starting at the first neighbour and running counter-clockwise,
then assign each sample a distinct candidate of the 1-3-ring (dummies included) by minimum total Euclidean
distance. SP and SPD are the spiral baselines of SpiralNet++ / Neural3DMM.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from meshops.ellipse import closest_parameter, ellipse_points, fit_ellipses
from meshops.neighbourhood import ASSIGNMENT_RINGS, Neighbourhood, quantise
from meshops.polyline import ClosedPolylines

# Polygon resolution used to measure arc length along a fitted ellipse (perimeter error ~ 1e-4).
ELLIPSE_POLYGON_POINTS = 128
# Vertices whose assignment costs are computed together: bounds memory at (chunk x 40 candidates x L) floats.
_CHUNK = 2048


def spiral_depth(length: int, dilation: int) -> int:
    """Rings a spiral draws on: enough to reach `length` entries at `dilation` around a regular valence-6
    vertex, and never fewer than the 3-ring RC and EC use, so a spiral pads only where that runs out."""
    needed = (length - 1) * dilation
    depth = 1
    while 3 * depth * (depth + 1) < needed:
        depth += 1
    return max(depth, ASSIGNMENT_RINGS)


def ring_samples(nb: Neighbourhood, n_samples: int) -> np.ndarray:
    """RC samples (V, n_samples, 3): uniform in length along the closed one-ring, the first at the first neighbour."""
    return ClosedPolylines.of(nb.ring_positions(), nb.ring_count).sample(n_samples)


def ellipse_samples(nb: Neighbourhood, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """EC samples (V, n_samples, 3) on the best-fit ellipse of the projected one-ring (+ dummy), and a mask of the
    vertices whose fit was degenerate and that fall back to their RC samples."""
    n = len(nb.vertices)
    owner = np.broadcast_to(np.arange(n)[:, None], nb.ring.shape)
    flat = nb.tangent_coordinates(nb.ring_positions(), owner)
    real = nb.ring != -1
    radius = np.sum(np.where(real, np.linalg.norm(flat, axis=-1), 0.0), axis=1) / nb.ring_count
    flat = flat / radius[:, None, None]
    centre, axes, rotation, ok = fit_ellipses(flat, real)
    # Arc length is measured on a fine inscribed polygon that starts at the ellipse point nearest the first
    # neighbour; the samples are then placed on the ellipse itself.
    start = closest_parameter(centre, axes, rotation, flat[:, 0])
    step = 2 * np.pi / ELLIPSE_POLYGON_POINTS
    theta = start[:, None] + step * np.arange(ELLIPSE_POLYGON_POINTS)[None, :]
    segment, fraction = ClosedPolylines.of(ellipse_points(centre, axes, rotation, theta)).locate(n_samples)
    on_ellipse = ellipse_points(centre, axes, rotation, start[:, None] + step * (segment + fraction))
    on_ellipse = on_ellipse * radius[:, None, None]
    samples = (nb.vertices[:, None, :] + on_ellipse[..., :1] * nb.tangent[:, None, :]
               + on_ellipse[..., 1:] * nb.bitangent[:, None, :])
    fallback = ~ok
    samples[fallback] = ring_samples(nb, n_samples)[fallback]
    return samples, fallback


def assignment_table(nb: Neighbourhood, samples: np.ndarray) -> np.ndarray:
    """Conv table (V, 1 + S) from samples (V, S, 3) by rectangular assignment to the 1-3-ring and dummies.

    The objective is lexicographic: first use every one-ring vertex and the one-ring dummy (the corners of the
    ring the samples were drawn from), then minimise the total sample-to-candidate distance. The paper observes
    that its tables "tend to include all the one-ring neighbours"; ranking them first makes that hold whenever
    the valence allows, instead of losing a neighbour where two sit close together on the ring.
    """
    n, n_samples = samples.shape[:2]
    in_disk = (nb.distance >= 1) & (nb.distance <= ASSIGNMENT_RINGS)
    owner = np.r_[nb.owner[in_disk], nb.dummy_owner]
    order = np.argsort(owner, kind="stable")
    owner = owner[order]
    label = np.r_[nb.neighbour[in_disk] + 1, np.zeros(len(nb.dummy_owner), dtype=np.int64)][order]
    position = np.concatenate([nb.vertices[nb.neighbour[in_disk]], nb.dummy_position])[order]
    corner = np.r_[nb.distance[in_disk] == 1, nb.dummy_ring == 1][order]
    start = np.searchsorted(owner, np.arange(n + 1))

    bounds = start.tolist()
    chosen_sample, chosen_candidate = [], []
    for first in range(0, n, _CHUNK):
        last = min(first + _CHUNK, n)
        rows = slice(bounds[first], bounds[last])
        gap = np.linalg.norm(position[rows, None, :] - samples[owner[rows]], axis=-1)
        cost = quantise(gap / nb.scale)
        if not np.isfinite(cost).all():  # the neighbourhood's frames and dummies are built to make this impossible
            v = owner[rows][np.argmax(~np.isfinite(cost).all(axis=1))]
            raise RuntimeError(f"vertex {v}: non-finite assignment cost (a NaN or infinite sample or candidate)")
        # Costs are integers below 2**53, so adding the penalty keeps them exact and ties reproducible.
        cost += np.where(corner[rows], 0.0, n_samples * cost.max() + 1)[:, None]
        for v in range(first, last):
            candidate, sample = linear_sum_assignment(cost[bounds[v] - bounds[first]:bounds[v + 1] - bounds[first]])
            chosen_candidate.append(candidate + bounds[v])
            chosen_sample.append(sample + (1 + n_samples) * v)
    table = np.zeros((n, 1 + n_samples), dtype=np.int64)
    table[:, 0] = np.arange(1, n + 1)
    table.ravel()[np.concatenate(chosen_sample) + 1] = label[np.concatenate(chosen_candidate)]
    return table


def spiral_table(nb: Neighbourhood, length: int, dilation: int) -> np.ndarray:
    """Spiral rows (V, length): the vertex, then its rings outwards, each counter-clockwise from the first
    neighbour's direction (the one-ring in its topological order), keeping every `dilation`-th entry and padding
    with 0 where the neighbourhood runs out (at boundaries and on tiny meshes)."""
    n = len(nb.vertices)
    owner = nb.owner
    depth = spiral_depth(length, dilation)
    keep = (nb.distance >= 1) & (nb.distance <= depth)
    owner, other, ring_index = owner[keep], nb.neighbour[keep], nb.distance[keep]

    flat = nb.tangent_coordinates(nb.vertices[other], owner)
    # Quantised before wrapping, so a vertex straight along the first neighbour's direction stays at angle 0.
    angle = np.mod(quantise(np.arctan2(flat[:, 1], flat[:, 0])), quantise(2 * np.pi))
    one_ring = ring_index == 1
    angle[one_ring] = np.argmax(nb.ring[owner[one_ring]] == other[one_ring, None], axis=1)
    order = np.lexsort((other, angle, ring_index, owner))
    owner, other = owner[order], other[order]
    group_start = np.searchsorted(owner, owner)
    position = 1 + np.arange(len(owner)) - group_start

    table = np.zeros((n, length), dtype=np.int64)
    table[:, 0] = np.arange(1, n + 1)
    slot = position // dilation
    take = (position % dilation == 0) & (slot < length)
    table[owner[take], slot[take]] = other[take] + 1
    return table


def conv_table(nb: Neighbourhood, kind: str, length: int) -> tuple[np.ndarray, int]:
    """Table (V, length) int32 of one kind, and how many vertices fell back from EC to RC sampling."""
    if kind == "RC":
        return assignment_table(nb, ring_samples(nb, length - 1)).astype(np.int32), 0
    if kind == "EC":
        samples, fallback = ellipse_samples(nb, length - 1)
        return assignment_table(nb, samples).astype(np.int32), int(fallback.sum())
    if kind in ("SP", "SPD"):
        return spiral_table(nb, length, 1 if kind == "SP" else 2).astype(np.int32), 0
    raise ValueError(f"unknown convolution kind {kind!r}; expected RC, EC, SP or SPD")

