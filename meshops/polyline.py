"""Uniform arc-length sampling of closed polylines, batched: one padded polyline per vertex."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClosedPolylines:
    points: np.ndarray      # (N, K, d), padding replaced by the first point so that it adds zero length
    ends: np.ndarray        # (N, K, d) the end of each segment: the next point, the first after the last
    cumulative: np.ndarray  # (N, K + 1) arc length at each point, the total last

    @classmethod
    def of(cls, points: np.ndarray, count: np.ndarray | None = None) -> "ClosedPolylines":
        """Polylines from padded points (N, K, d) with `count` (N,) real points per row (default: all)."""
        n, k = points.shape[:2]
        if count is not None:
            padding = np.arange(k)[None, :] >= count[:, None]
            points = np.where(padding[..., None], points[:, :1], points)
        ends = np.roll(points, -1, axis=1)
        length = np.sqrt(np.sum((ends - points) ** 2, axis=-1))
        return cls(points, ends, np.concatenate([np.zeros((n, 1)), np.cumsum(length, axis=1)], axis=1))

    def locate(self, n_samples: int, start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Segment index (N, S) and fraction along it (N, S) of `n_samples` points spaced length / n_samples,
        the first at arc-length position `start` (N,) (default 0: the first point)."""
        n, k = self.points.shape[:2]
        total = self.cumulative[:, -1:]
        offset = np.zeros((n, 1)) if start is None else start[:, None]
        target = np.mod(offset + total * np.arange(n_samples)[None, :] / n_samples, total)
        # One sorted search for all rows: row r's arc lengths, normalised to [0, 1], are shifted to [r, r + 1].
        row = np.arange(n)[:, None]
        keys = (row + self.cumulative / total).ravel()
        at = np.searchsorted(keys, (row + target / total).ravel(), side="right").reshape(n, n_samples) - 1
        segment = np.clip(at - row * (k + 1), 0, k - 1)
        seg_start = np.take_along_axis(self.cumulative, segment, axis=1)
        seg_length = np.take_along_axis(self.cumulative, segment + 1, axis=1) - seg_start
        fraction = np.clip((target - seg_start) / np.where(seg_length > 0, seg_length, 1.0), 0.0, 1.0)
        return segment, fraction

    def sample(self, n_samples: int, start: np.ndarray | None = None) -> np.ndarray:
        """The points (N, n_samples, d) located by `locate`, counter-clockwise in storage order."""
        segment, fraction = self.locate(n_samples, start)
        a = np.take_along_axis(self.points, segment[..., None], axis=1)
        b = np.take_along_axis(self.ends, segment[..., None], axis=1)
        return a + fraction[..., None] * (b - a)
