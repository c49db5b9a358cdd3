"""A frame's comparison picture: one camera for every frame shown, so the garment fills its panels across a whole
motion, and one colour scale for every error map."""
from __future__ import annotations

import numpy as np

from geometry.shapes import grid_patch
from render_checks import box, cloth_mask, column_groups, tube
from viz.comparison import Comparison, FrameMeshes, comparison_image, fit_comparison
from viz.render import fit_view, shading, value_colors

PANEL_HEIGHT = 2.0                     # inches at 100 dpi: 200-pixel panels, for speed


def test_garment_fills_each_panel_over_a_motion_and_the_error_scale_is_the_percentile():
    low, low_faces = tube(around=8, along=4)
    truth, faces = tube()
    frames = [truth + [0.3 * k, 0.05 * k, 0.0] for k in range(3)]              # the garment moves
    errors = [np.full(len(truth), 0.001), np.linspace(0.0, 0.1, 101)]
    comparison = fit_comparison([low + [0.3 * k, 0.05 * k, 0.0] for k in range(3)], frames, low_faces, faces, errors)
    assert np.isclose(comparison.vmax, np.percentile(np.concatenate(errors), 99))
    body = box([-1.5, -1.0, -2.0], [2.0, 2.0, -0.25])
    panel_px = PANEL_HEIGHT * 100
    for k in (0, 2):                                                           # first and last frame, one camera
        frame = FrameMeshes(low + [0.3 * k, 0.05 * k, 0.0], frames[k] + 0.002, frames[k], frames[k] + 0.001, body)
        image = comparison_image(comparison, frame, f"frame {k}", predictor_error=False, panel_height=PANEL_HEIGHT,
                                 supersample=1)
        groups = [(a, b) for a, b in column_groups(cloth_mask(image)) if b - a > 0.1 * panel_px]
        assert len(groups) == 3                                    # input, truth, network: plain cloth
        for first, last in groups:
            rows = np.flatnonzero(cloth_mask(image[:, first:last + 1]).any(axis=1))
            assert rows[-1] - rows[0] + 1 >= 0.4 * panel_px                   # issue 17's acceptance


def test_both_error_maps_use_the_comparison_colour_scale():
    # A flat square facing the camera: every pixel of an error panel has the same shade, so its colour is known.
    square, faces = grid_patch(12, 12)
    square = square - [0.5, 0.5, 0.0]
    low, low_faces = grid_patch(3, 3)
    view = fit_view([square], elevation=0.0, azimuth=0.0, margin=0.1)
    comparison = Comparison(low_faces, faces, view, vmax=0.02)
    # Loop subdivision 0.02 off (the top of the scale), the network 0.005 (a quarter of it), both along z.
    frame = FrameMeshes(low - [0.5, 0.5, 0.0], square + [0, 0, 0.02], square, square + [0, 0, 0.005])
    image = comparison_image(comparison, frame, "", panel_height=PANEL_HEIGHT, supersample=1).astype(float) / 255
    diffuse, _ = shading(np.array([[0.0, 0.0, 1.0]]))
    square_px = (PANEL_HEIGHT * 100 / 1.2) ** 2                 # the square and its margins fill a panel
    for value in (1.0, 0.25):
        expected = value_colors(np.array([value]), 1.0)[0, :3] * (0.5 + 0.5 * diffuse[0])
        near = (np.abs(image - expected).max(axis=2) < 0.03).sum()
        assert 0.8 * square_px < near < 1.2 * square_px             # one panel's square in that colour
