"""Uniform arc-length sampling of closed polylines, batched: one padded polyline per vertex."""
from __future__ import annotations

import numpy as np


def _closed_segments(points: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Padded points with the first point repeated after the last real one, so padding adds zero length.

    Returns the points (N, K, d), the segment ends (N, K, d) and the cumulative length at each point (N, K + 1).
    """
    n, k = points.shape[:2]
    padding = np.arange(k)[None, :] >= count[:, None]
    points = np.where(padding[..., None], points[:, :1], points)
    ends = np.roll(points, -1, axis=1)
    length = np.linalg.norm(ends - points, axis=-1)
    cumulative = np.concatenate([np.zeros((n, 1)), np.cumsum(length, axis=1)], axis=1)
    return points, ends, cumulative


def sample_closed_polyline(points: np.ndarray, count: np.ndarray, n_samples: int,
                           start: np.ndarray | None = None) -> np.ndarray:
    """`n_samples` points spaced length / n_samples along each closed polyline, counter-clockwise in storage order.

    points (N, K, d) padded, count (N,) real points per row; `start` (N,) the arc-length position of the first
    sample (default 0: the first point). Returns (N, n_samples, d).
    """
    segment, fraction = locate_arc_samples(points, count, n_samples, start)
    points, ends, _ = _closed_segments(points, count)
    a = np.take_along_axis(points, segment[..., None], axis=1)
    b = np.take_along_axis(ends, segment[..., None], axis=1)
    return a + fraction[..., None] * (b - a)


def locate_arc_samples(points: np.ndarray, count: np.ndarray, n_samples: int,
                       start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where the samples of `sample_closed_polyline` fall: segment index (N, S) and fraction along it (N, S)."""
    _, _, cumulative = _closed_segments(points, count)
    total = cumulative[:, -1:]
    offset = np.zeros((len(points), 1)) if start is None else start[:, None]
    target = np.mod(offset + total * np.arange(n_samples)[None, :] / n_samples, total)
    segment = np.sum(cumulative[:, None, 1:] <= target[:, :, None], axis=-1)
    segment = np.minimum(segment, points.shape[1] - 1)
    seg_start = np.take_along_axis(cumulative, segment, axis=1)
    seg_length = np.take_along_axis(cumulative, segment + 1, axis=1) - seg_start
    fraction = np.where(seg_length > 0, (target - seg_start) / np.where(seg_length > 0, seg_length, 1), 0.0)
    return segment, fraction


def closest_arc_position(points: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Arc-length position (N,) of the point of each closed polyline (N, M, d), all M points real, nearest `query`."""
    points, ends, cumulative = _closed_segments(points, np.full(len(points), points.shape[1]))
    direction = ends - points
    length2 = np.einsum("nmd,nmd->nm", direction, direction)
    t = np.clip(np.einsum("nmd,nmd->nm", query[:, None] - points, direction) / length2, 0.0, 1.0)
    gap = np.linalg.norm(points + t[..., None] * direction - query[:, None], axis=-1)
    best = np.argmin(gap, axis=1)
    rows = np.arange(len(points))
    return cumulative[rows, best] + t[rows, best] * np.sqrt(length2[rows, best])
