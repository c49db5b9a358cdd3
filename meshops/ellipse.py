"""Batched direct least-squares ellipse fitting for the EC convolution (paper 3.1, [OZM04]).

The fit minimises the algebraic distance of the conic a x^2 + b xy + c y^2 + d x + e y + f = 0 to the points
under the ellipse-specific constraint 4ac - b^2 = 1 (Fitzgibbon et al. 1999), in the numerically stable
partitioned form of Halir & Flusser (1998) that O'Leary & Zsombor-Murray (2004) build on.
"""
from __future__ import annotations

import numpy as np

# An ellipse used as a convolution ring must surround its vertex and stay about the size of the one-ring;
# a fit more than this many ring radii across is a near-parabola through nearly collinear points.
MAX_AXIS_IN_RING_RADII = 3.0
_C1_INVERSE = np.array([[0.0, 0.0, 0.5], [0.0, -1.0, 0.0], [0.5, 0.0, 0.0]])


def fit_ellipses(points: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit one ellipse per row of 2-D points (N, K, 2) where `mask` (N, K) marks the real points.

    Points should be centred on their vertex and scaled to about unit size. Returns `centre` (N, 2), `axes`
    (N, 2) semi-axis lengths, `rotation` (N, 2, 2) with det +1 (columns = axis directions), and `ok` (N,): False
    where the fit is degenerate (fewer than five points, collinear points, no ellipse, or an ellipse that does
    not surround the origin or is far larger than the points).
    """
    w = mask.astype(np.float64)
    x, y = points[..., 0], points[..., 1]
    quadratic = np.stack([x * x, x * y, y * y], axis=-1)
    linear = np.stack([x, y, np.ones_like(x)], axis=-1)
    weighted_quadratic = np.swapaxes(quadratic * w[..., None], 1, 2)
    s1 = weighted_quadratic @ quadratic
    s2 = weighted_quadratic @ linear
    s3 = np.swapaxes(linear * w[..., None], 1, 2) @ linear

    ok = (mask.sum(axis=1) >= 5) & (np.linalg.cond(s3) < 1e10)
    s3 = np.where(ok[:, None, None], s3, np.eye(3))
    t = -np.linalg.solve(s3, np.swapaxes(s2, 1, 2))
    reduced = _C1_INVERSE @ (s1 + s2 @ t)
    values, vectors = np.linalg.eig(reduced)
    vectors = vectors.real
    constraint = 4 * vectors[:, 0, :] * vectors[:, 2, :] - vectors[:, 1, :] ** 2
    ellipse_like = (constraint > 0) & (np.abs(values.imag) < 1e-9 * (1 + np.abs(values.real)))
    ok &= ellipse_like.sum(axis=1) == 1
    choice = np.argmax(ellipse_like, axis=1)
    quadric = np.take_along_axis(vectors, choice[:, None, None], axis=2)[..., 0]
    linear_part = (t @ quadric[..., None])[..., 0]
    a, b, c = quadric[:, 0], quadric[:, 1], quadric[:, 2]
    d, e, f = linear_part[:, 0], linear_part[:, 1], linear_part[:, 2]

    form = np.stack([np.stack([a, b / 2], -1), np.stack([b / 2, c], -1)], axis=-2)
    form = np.where(ok[:, None, None], form, np.eye(2))
    centre = np.linalg.solve(2 * form, -np.stack([d, e], axis=-1)[..., None])[..., 0]
    level = -(f + (d * centre[:, 0] + e * centre[:, 1]) / 2)
    eigenvalues, rotation = np.linalg.eigh(form)
    with np.errstate(divide="ignore", invalid="ignore"):
        axes = np.sqrt(level[:, None] / eigenvalues)
    ok &= np.all(np.isfinite(axes) & (axes > 0), axis=1)
    axes = np.where(ok[:, None], axes, 1.0)
    rotation[:, :, 1] *= np.sign(np.linalg.det(rotation))[:, None]

    local = np.einsum("nji,nj->ni", rotation, -centre) / axes
    ok &= np.sum(local ** 2, axis=1) < 1.0
    radius = np.max(np.where(mask, np.linalg.norm(points, axis=-1), 0.0), axis=1)
    ok &= axes.max(axis=1) <= MAX_AXIS_IN_RING_RADII * radius
    return centre, axes, rotation, ok


def ellipse_points(centre: np.ndarray, axes: np.ndarray, rotation: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Points (N, M, 2) at parameters theta (N, M) of each ellipse; theta increases counter-clockwise."""
    along, across = axes[:, None, 0] * np.cos(theta), axes[:, None, 1] * np.sin(theta)
    return np.stack([centre[:, None, 0] + rotation[:, None, 0, 0] * along + rotation[:, None, 0, 1] * across,
                     centre[:, None, 1] + rotation[:, None, 1, 0] * along + rotation[:, None, 1, 1] * across], axis=-1)


def closest_parameter(centre: np.ndarray, axes: np.ndarray, rotation: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Parameter theta (N,) of the point of each ellipse nearest `query` (N, 2).

    A coarse scan brackets the nearest point, Newton's method on d/dtheta |p(theta) - q|^2 / 2 = 0 refines it.
    The answer depends only on the ellipse, not on how its axes were ordered or signed, which matters for
    circles, whose axes are arbitrary.
    """
    local = np.einsum("nji,nj->ni", rotation, query - centre)
    a, b = axes[:, 0:1], axes[:, 1:2]
    u, w = local[:, 0:1], local[:, 1:2]
    scan = np.arange(64) * 2 * np.pi / 64
    theta = scan[np.argmin((a * np.cos(scan) - u) ** 2 + (b * np.sin(scan) - w) ** 2, axis=1)][:, None]
    for _ in range(6):
        slope = (b * b - a * a) * np.sin(theta) * np.cos(theta) + a * u * np.sin(theta) - b * w * np.cos(theta)
        curvature = (b * b - a * a) * np.cos(2 * theta) + a * u * np.cos(theta) + b * w * np.sin(theta)
        theta = np.where(curvature > 0, theta - slope / np.where(curvature > 0, curvature, 1.0), theta)
    return theta[:, 0]
