"""Closed-polyline sampling and the direct least-squares ellipse fit, on analytic cases."""
import numpy as np

from meshops.ellipse import closest_parameter, ellipse_points, fit_ellipses
from meshops.polyline import ClosedPolylines


def test_samples_are_evenly_spaced_along_a_closed_square_from_its_first_corner():
    square = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [9.0, 9.0]]])  # last entry is padding
    samples = ClosedPolylines.of(square, np.array([4])).sample(8)
    expected = [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1], [0, 1], [0, 0.5]]
    assert np.allclose(samples[0], expected)
    shifted = ClosedPolylines.of(square, np.array([4])).sample(4, start=np.array([0.25]))
    assert np.allclose(shifted[0], [[0.25, 0], [1, 0.25], [0.75, 1], [0, 0.75]])


def _ellipse_points(centre, axes, angle, theta):
    c, s = np.cos(angle), np.sin(angle)
    local = np.stack([axes[0] * np.cos(theta), axes[1] * np.sin(theta)], axis=-1)
    return centre + local @ np.array([[c, s], [-s, c]])


def test_fit_recovers_an_ellipse_through_exact_points():
    theta = np.array([0.1, 0.9, 1.7, 2.8, 3.5, 4.4, 5.6])
    points = _ellipse_points(np.array([0.1, -0.05]), (1.3, 0.6), 0.4, theta)[None]
    centre, axes, rotation, ok = fit_ellipses(points, np.ones((1, 7), dtype=bool))
    assert ok[0]
    assert np.allclose(centre[0], [0.1, -0.05], atol=1e-9)
    assert np.allclose(np.sort(axes[0]), [0.6, 1.3], atol=1e-9)
    assert np.isclose(np.linalg.det(rotation[0]), 1.0)
    polygon = ellipse_points(centre, axes, rotation, np.linspace(0, 2 * np.pi, 64, endpoint=False)[None])[0]
    # Every polygon point lies on the true ellipse, and the polygon turns counter-clockwise.
    c, s = np.cos(0.4), np.sin(0.4)
    local = (polygon - [0.1, -0.05]) @ np.array([[c, -s], [s, c]])
    assert np.allclose((local[:, 0] / 1.3) ** 2 + (local[:, 1] / 0.6) ** 2, 1.0, atol=1e-9)
    area2 = np.sum(polygon[:, 0] * np.roll(polygon[:, 1], -1) - np.roll(polygon[:, 0], -1) * polygon[:, 1])
    assert area2 > 0


def test_least_squares_fit_of_noisy_points_stays_close():
    rng = np.random.default_rng(3)
    theta = np.sort(rng.uniform(0, 2 * np.pi, 9))
    points = _ellipse_points(np.zeros(2), (1.0, 0.7), -0.3, theta) + rng.normal(0, 0.01, (9, 2))
    centre, axes, _, ok = fit_ellipses(points[None], np.ones((1, 9), dtype=bool))
    assert ok[0] and np.allclose(np.sort(axes[0]), [0.7, 1.0], atol=0.05) and np.allclose(centre[0], 0, atol=0.05)


def test_degenerate_fits_are_flagged():
    circle = _ellipse_points(np.zeros(2), (1.0, 1.0), 0.0, np.linspace(0, 2 * np.pi, 6, endpoint=False))
    line = np.stack([np.linspace(-1, 1, 6), np.zeros(6)], axis=1)
    away = circle + [3.0, 0.0]  # a fine ellipse that does not surround the origin
    batch = np.stack([circle, line, away, circle])
    mask = np.ones((4, 6), dtype=bool)
    mask[3, 4:] = False  # only four points: a conic is not determined
    _, _, _, ok = fit_ellipses(batch, mask)
    assert list(ok) == [True, False, False, False]


def test_closest_parameter_finds_the_nearest_ellipse_point_whatever_the_axis_order():
    rng = np.random.default_rng(5)
    centre, axes = np.array([[0.2, -0.1]]), np.array([[1.5, 0.5]])
    rotation = np.array([[[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]]])
    dense = ellipse_points(centre, axes, rotation, np.linspace(0, 2 * np.pi, 200001)[None])[0]
    for query in rng.uniform(-2, 2, (20, 2)):
        theta = closest_parameter(centre, axes, rotation, query[None])
        ours = np.linalg.norm(ellipse_points(centre, axes, rotation, theta[:, None])[0, 0] - query)
        scanned = np.min(np.linalg.norm(dense - query, axis=1))  # within ~1e-9 above the true minimum
        assert scanned - 1e-8 <= ours <= scanned + 1e-12
    # A circle has no preferred axes: any rotation gives the same nearest point.
    query = np.array([[0.3, 0.9]])
    points = [ellipse_points(np.zeros((1, 2)), np.ones((1, 2)), turn[None],
                             closest_parameter(np.zeros((1, 2)), np.ones((1, 2)), turn[None], query)[:, None])[0, 0]
              for turn in (np.eye(2), np.array([[0.0, -1.0], [1.0, 0.0]]))]
    assert np.allclose(points[0], query[0] / np.linalg.norm(query)) and np.allclose(points[1], points[0])
