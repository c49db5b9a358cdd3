"""The z-buffer rasteriser against a brute-force reference: every pixel centre against every triangle."""
from __future__ import annotations

import numpy as np

from viz.raster import EMPTY, rasterize


def brute_force(screen, triangles, height, width):
    """Nearest covering triangle and its depth per pixel centre, one small linear solve at a time."""
    nearest = np.full((height, width), EMPTY)
    depth = np.full((height, width), -np.inf)
    for row in range(height):
        for column in range(width):
            centre = np.array([column + 0.5, row + 0.5])
            for k, (a, b, c) in enumerate(screen[triangles]):
                matrix = np.column_stack([b[:2] - a[:2], c[:2] - a[:2]])
                if abs(np.linalg.det(matrix)) < 1e-9:
                    continue
                s, t = np.linalg.solve(matrix, centre - a[:2])
                z = a[2] + s * (b[2] - a[2]) + t * (c[2] - a[2])
                if min(s, t, 1 - s - t) > 1e-6 and z > depth[row, column]:
                    nearest[row, column], depth[row, column] = k, z
    return nearest, depth


def test_rasterize_matches_brute_force_on_crossing_triangles():
    rng = np.random.default_rng(3)
    height, width = 18, 23
    # Random triangles reaching past the image on every side, at random slanted depths: they cross each other.
    screen = np.column_stack([rng.uniform(-5, width + 5, 24), rng.uniform(-5, height + 5, 24), rng.normal(size=24)])
    triangles = rng.permutation(24).reshape(8, 3)
    seen = rasterize(screen, triangles, height, width)
    reference, reference_depth = brute_force(screen, triangles, height, width)
    # Pixel centres on an edge (within 1e-6) may go either way; with random floats there are none.
    np.testing.assert_array_equal(seen.triangle, reference)
    np.testing.assert_allclose(seen.depth, reference_depth, atol=1e-4)
    hit = seen.triangle != EMPTY
    assert 0.3 < hit.mean() < 1.0                                     # a real mix of covered and empty
    corners = screen[triangles[seen.triangle[hit]]]                    # weights reproduce the pixel centres
    rows, columns = np.nonzero(hit)
    np.testing.assert_allclose((seen.barycentric[hit][:, :, None] * corners[:, :, :2]).sum(axis=1),
                               np.column_stack([columns + 0.5, rows + 0.5]), atol=1e-3)


def test_shared_edge_leaves_no_crack_and_edge_on_triangles_cover_nothing():
    square = np.array([[1.0, 1, 0], [9, 1, 0], [9, 9, 0], [1, 9, 0], [5, 5, 2], [5, 5, 3]])
    seen = rasterize(square, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 0]]), 10, 10)
    assert (seen.triangle[1:9, 1:9] != EMPTY).all()                   # the diagonal is covered throughout
    assert (seen.triangle != 2).all()                                 # a triangle seen edge-on has no pixel
    assert (seen.triangle[0] == EMPTY).all() and (seen.triangle[:, 9] == EMPTY).all()


def test_long_thin_slivers_at_every_slope_match_brute_force():
    """The rows' column ranges (only the columns between the edges' crossings are candidates) lose no centre of
    triangles far longer than wide, at every slope, crossing the image's borders, overlapping."""
    rng = np.random.default_rng(11)
    height, width = 21, 27
    centres = np.column_stack([rng.uniform(0, width, 10), rng.uniform(0, height, 10)])
    angles = rng.uniform(0, np.pi, 10)
    along = 25 * np.column_stack([np.cos(angles), np.sin(angles)])
    across = rng.uniform(0.5, 4.0, 10)[:, None] * np.column_stack([-np.sin(angles), np.cos(angles)])
    points = np.concatenate([centres - along, centres + along, centres + across])       # (30, 2)
    screen = np.column_stack([points, rng.normal(size=30)])
    triangles = np.column_stack([np.arange(10), np.arange(10, 20), np.arange(20, 30)])
    seen = rasterize(screen, triangles, height, width)
    reference, reference_depth = brute_force(screen, triangles, height, width)
    np.testing.assert_array_equal(seen.triangle, reference)
    np.testing.assert_allclose(seen.depth, reference_depth, atol=1e-4)
    assert 0.1 < (seen.triangle != EMPTY).mean() < 0.9
