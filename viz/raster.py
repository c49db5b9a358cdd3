"""A z-buffer triangle rasteriser in numpy: which surface each pixel sees, exactly.

matplotlib's 3D axes sort whole faces by depth (painter's algorithm), so a large body face whose centre is nearer
than a small cloth face in front of it is drawn over the cloth: penetration and a sorting error look the same.
Here every pixel keeps the nearest surface point, so the body shows through the cloth only where it really is in
front of it. Every triangle is expanded at once into the pixel centres of its bounding box's rows, each row only
between the triangle's edges (triangles of the meshes we draw cover a few to a few hundred pixels), the centres
inside it are kept, and the nearest one per pixel wins; no loop over triangles or pixels.
"""
from __future__ import annotations

import dataclasses

import numpy as np

EMPTY = -1              # `Fragments.triangle` where no triangle covers the pixel


@dataclasses.dataclass(frozen=True)
class Fragments:
    """The visible surface at each pixel centre of an (H, W) image."""

    triangle: np.ndarray      # (H, W) int: index of the triangle seen, EMPTY where none
    barycentric: np.ndarray   # (H, W, 3): weights of that triangle's corners at the pixel centre (0 where empty)
    depth: np.ndarray         # (H, W): depth of the point seen, larger is nearer; -inf where empty


def rasterize(screen: np.ndarray, triangles: np.ndarray, height: int, width: int) -> Fragments:
    """The nearest triangle at every pixel centre (column i + 0.5, row j + 0.5).

    `screen` (N, 3): x in pixels (right), y in pixels (down), depth (towards the viewer); `triangles` (M, 3)
    indices into it. Triangles are two-sided; those with no area on screen (seen edge-on) cover nothing.
    """
    corners = np.asarray(screen, dtype=np.float64)[np.asarray(triangles)]              # (M, 3, 3)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    ab, ac = b - a, c - a
    det = ab[:, 0] * ac[:, 1] - ac[:, 0] * ab[:, 1]
    first = np.clip(np.ceil(corners[:, :, :2].min(axis=1) - 0.5), 0, [width, height]).astype(np.int32)
    last = np.clip(np.floor(corners[:, :, :2].max(axis=1) - 0.5), -1, [width - 1, height - 1]).astype(np.int32)
    span = last - first + 1                                                              # (M, 2) columns, rows
    count = np.where((span > 0).all(axis=1) & (np.abs(det) > 1e-12), span[:, 0] * span[:, 1], 0)
    # The barycentric weights (s, t) of b and c solve centre = a + s ab + t ac: affine in the pixel centre, so
    # each is three coefficients per triangle, taken relative to the triangle's first pixel centre.
    with np.errstate(divide="ignore", invalid="ignore"):
        origin = first + 0.5 - a[:, :2]
        s_coef = np.stack([ac[:, 1], -ac[:, 0], origin[:, 0] * ac[:, 1] - origin[:, 1] * ac[:, 0]], 1) / det[:, None]
        t_coef = np.stack([-ab[:, 1], ab[:, 0], origin[:, 1] * ab[:, 0] - origin[:, 0] * ab[:, 1]], 1) / det[:, None]
    # Per-triangle values are spread over its candidates with np.repeat (a sequential copy, several times faster
    # than gathering them with the candidates' triangle ids). Candidates are not the whole bounding box: on each
    # row of it, only the columns between where the three edge functions (s, t, 1 - s - t, linear along the row)
    # cross zero, widened by a column each side so that rounding cannot lose a centre; the exact test below
    # decides. A bounding box is twice a triangle's area or more (a body's long capsule facets: far more).
    rows = np.where(count > 0, span[:, 1], 0)
    row_tri = np.repeat(np.arange(len(corners), dtype=np.int32), rows)
    drow = _positions_in_groups(rows)
    s_row = np.repeat(s_coef[:, 1], rows) * drow + np.repeat(s_coef[:, 2], rows)       # s at the row's column 0
    t_row = np.repeat(t_coef[:, 1], rows) * drow + np.repeat(t_coef[:, 2], rows)
    s_col, t_col = np.repeat(s_coef[:, 0], rows), np.repeat(t_coef[:, 0], rows)
    last_column = np.repeat(span[:, 0] - 1, rows)
    low, high = np.zeros(len(row_tri)), last_column.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for slope, offset in ((s_col, s_row), (t_col, t_row), (-s_col - t_col, 1 - s_row - t_row)):
            cross = -offset / slope                           # value + slope * column >= 0 beyond this column
            low = np.where(slope > 0, np.maximum(low, cross), low)
            high = np.where(slope < 0, np.minimum(high, cross), high)
            high = np.where((slope == 0) & (offset < -1e-6), -1.0, high)           # never inside on this row
    low = np.clip(np.ceil(low) - 1, 0, last_column + 1).astype(np.int32)      # clipped: a crossing may be inf
    high = np.clip(np.floor(high) + 1, -1, last_column).astype(np.int32)
    width_on_row = np.maximum(high - low + 1, 0)
    tri = np.repeat(row_tri, width_on_row)
    dcol = np.repeat(low, width_on_row) + _positions_in_groups(width_on_row)
    drow = np.repeat(drow, width_on_row)
    fcol, frow = dcol.astype(np.float32), drow.astype(np.float32)
    per_candidate = [np.repeat(np.repeat(coef.astype(np.float32), rows), width_on_row)
                     for coef in (*s_coef.T, *t_coef.T)]
    s = per_candidate[0] * fcol + per_candidate[1] * frow + per_candidate[2]
    t = per_candidate[3] * fcol + per_candidate[4] * frow + per_candidate[5]
    # A centre exactly on a shared edge is inside both triangles (no cracks); the depth test picks one.
    inside = np.flatnonzero((s >= -1e-6) & (t >= -1e-6) & (s + t <= 1 + 1e-6))
    tri, s, t = np.take(tri, inside), np.take(s, inside), np.take(t, inside)
    pixel = ((np.take(first[:, 1], tri) + np.take(drow, inside)) * width
             + np.take(first[:, 0], tri) + np.take(dcol, inside))
    depth = np.take(a[:, 2], tri) + s * np.take(ab[:, 2], tri) + t * np.take(ac[:, 2], tri)
    nearest = np.full(height * width, -np.inf)
    np.maximum.at(nearest, pixel, depth)
    # Of the fragments at their pixel's nearest depth (ties are equally right), the last one: one winner per
    # pixel, so that its triangle and weights agree (numpy does not promise which of repeated indices it writes).
    fragment = np.flatnonzero(depth == nearest[pixel])
    winner = np.full(height * width, -1)
    np.maximum.at(winner, pixel[fragment], fragment)
    seen = winner >= 0
    won = winner[seen]
    triangle = np.full(height * width, EMPTY)
    triangle[seen] = tri[won]
    weights = np.zeros((height * width, 3), dtype=np.float32)
    weights[seen] = np.stack([1 - s[won] - t[won], s[won], t[won]], axis=1)
    return Fragments(triangle.reshape(height, width), weights.reshape(height, width, 3),
                     np.where(seen, nearest, -np.inf).reshape(height, width))


def _positions_in_groups(counts: np.ndarray) -> np.ndarray:
    """0, 1, ..., counts[0] - 1, 0, 1, ..., counts[1] - 1, ...: each element's place in its group (int32)."""
    return (np.arange(int(counts.sum()), dtype=np.int32)
            - np.repeat((np.cumsum(counts) - counts).astype(np.int32), counts))
