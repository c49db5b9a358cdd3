"""Renders as a person sees them: the garment fills its panels, the body shows only where it is in front of the
cloth, one camera holds still across frames, and the colours mean what the legend says."""
from __future__ import annotations

import matplotlib.image
import numpy as np

from geometry.shapes import cube_sphere, grid_patch
from render_checks import body_mask, box, cloth_mask, column_groups, tube
from viz.render import (BODY_RGB, CLOTH_RGB, FLAT_VIEW_ANGLE, KEY_LIGHT, Panel, camera_axes, fit_view, panels_image,
                        render_panels, shading, value_colors)

DPI, PANEL_HEIGHT = 40, 4.0                      # small pictures for speed; panel height in pixels: 160


def test_garment_fills_each_panel_and_the_backdrop_does_not_widen_the_frame():
    vertices, faces = tube()
    # A box ten times the garment's size, standing right behind it: a frame fitted to it would shrink the cloth.
    body = box([-2.0, -2.0, -2.6], [2.0, 2.5, -0.22])
    errors = np.linspace(0, 1, len(vertices))
    image = panels_image([Panel("plain", vertices, faces), Panel("on the body", vertices, faces, backdrop=body),
                          Panel("error", vertices, faces, errors)], vmax=1.0, title="a <title>",
                         value_label="|error|", panel_height=PANEL_HEIGHT, dpi=DPI)
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    panel_px = PANEL_HEIGHT * DPI
    # The two plain panels (the colour bar's purple end is a narrow blue-ish group of its own).
    groups = [(first, last) for first, last in column_groups(cloth_mask(image)) if last - first > 0.1 * panel_px]
    assert len(groups) == 2
    for first, last in groups:
        rows = np.flatnonzero(cloth_mask(image[:, first:last + 1]).any(axis=1))
        assert rows[-1] - rows[0] + 1 >= 0.8 * panel_px                  # issue 17 asks for >= 40 %
        assert last - first + 1 >= 0.2 * panel_px                        # a 0.4 x 1.0 tube seen from the side
    left, right = groups
    assert body_mask(image[:, left[0]:left[1]]).sum() < 5                # no body where none is given
    assert body_mask(image[:, right[0]:right[1]]).sum() > 200            # the box shows around the tube
    error_part = image[:, right[1] + 5:].astype(float) / 255                # the error panel and its colour bar
    assert ((error_part[..., 0] - error_part[..., 2]) > 0.4).sum() > 500    # inferno's warm colours


def test_body_shows_through_cloth_only_where_it_pokes_through():
    # Camera straight down -z; cloth: a flat square at z = 0; a sphere behind it, first clear, then through it.
    cloth, cloth_faces = grid_patch(40, 40)
    cloth = cloth - [0.5, 0.5, 0.0]
    view = fit_view([cloth], elevation=0.0, azimuth=0.0, margin=0.1)        # 0.1 in front: the cap is kept
    for radius, expected in ((0.09, 0.0), (0.15, np.pi * (0.15 ** 2 - 0.1 ** 2))):     # disc where it pokes out
        sphere, sphere_faces = cube_sphere(12, radius)
        image = panels_image([Panel("", cloth, cloth_faces, backdrop=(sphere + [0, 0, -0.1], sphere_faces))], view,
                             panel_height=PANEL_HEIGHT, dpi=DPI)
        pixels_per_unit = PANEL_HEIGHT * DPI / 1.2                         # the square and its margins fill it
        area = body_mask(image).sum() / pixels_per_unit ** 2
        assert abs(area - expected) <= 0.15 * expected + 3 / pixels_per_unit ** 2


def test_a_view_fitted_to_all_frames_holds_the_camera_still():
    vertices, faces = tube()
    moved = vertices + [0.6, 0.0, 0.0]
    view = fit_view([vertices, moved])
    alone = [column_groups(cloth_mask(panels_image([Panel("", v, faces)], fit_view([v]), panel_height=PANEL_HEIGHT,
                                                   dpi=DPI))) for v in (vertices, moved)]
    still = [column_groups(cloth_mask(panels_image([Panel("", v, faces)], view, panel_height=PANEL_HEIGHT,
                                                   dpi=DPI))) for v in (vertices, moved)]
    assert alone[0] == alone[1]                                        # each fitted alone: the tube does not move
    shift = still[1][0][0] - still[0][0][0]
    scale = PANEL_HEIGHT * DPI / (view.window[3] - view.window[2])     # pixels per scene unit
    right = camera_axes(view.elevation, view.azimuth)[0]
    assert abs(shift - 0.6 * right[0] * scale) <= 2                     # one camera: the tube moves across it


def sheet(normal_axis: int, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A flat unit square through the origin whose normal is the scene axis `normal_axis` (1: horizontal)."""
    square, faces = grid_patch(n, n)
    square = square - [0.5, 0.5, 0.0]
    return np.roll(square, normal_axis - 2, axis=1), faces


def test_a_flat_cloth_seen_nearly_edge_on_is_seen_off_its_plane_from_the_side_the_camera_saw():
    """The default camera (12 degrees above the horizon, 30 degrees round) sees a horizontal sheet 12 degrees off
    its plane and one in the yz plane 29 degrees off: each turns to FLAT_VIEW_ANGLE, towards the same side; a
    flag in the xy plane (58 degrees off) and a tube (not flat) keep the camera."""
    least = np.sin(np.radians(FLAT_VIEW_ANGLE))
    for normal_axis in (1, 0):
        vertices, _ = sheet(normal_axis)
        view = fit_view([vertices])
        towards = camera_axes(view.elevation, view.azimuth)[2]
        before = camera_axes(12.0, 30.0)[2]
        assert np.isclose(towards[normal_axis], least) and before[normal_axis] > 0         # the same side
        kept = np.delete(towards, normal_axis) / np.linalg.norm(np.delete(towards, normal_axis))
        assert np.allclose(kept, np.delete(before, normal_axis) / np.linalg.norm(np.delete(before, normal_axis)))
    assert np.isclose(fit_view([sheet(1)[0]]).elevation, FLAT_VIEW_ANGLE)                 # from above, as before
    u0, u1, v0, v1 = fit_view([sheet(1)[0]]).window
    assert (u1 - u0) / (v1 - v0) < 1.0 / least + 0.01             # no sliver: at most 1 / sin of the angle
    for unchanged in (sheet(2)[0], tube()[0]):
        view = fit_view([unchanged])
        assert (view.elevation, view.azimuth) == (12.0, 30.0)


def test_a_flat_cloth_at_a_grazing_angle_is_shaded_evenly_without_outlines_inside():
    """Seen 8 degrees off its plane (the camera kept), a flat sheet's pixels all have its normal's shade: its
    depth changes by about seven pixel widths per pixel, evenly, which is no depth jump (it once darkened every
    pixel as an outline)."""
    vertices, faces = sheet(1, n=24)
    view = fit_view([vertices], elevation=8.0, azimuth=0.0, flat_angle=0.0)
    image = panels_image([Panel("", vertices, faces)], view, panel_height=PANEL_HEIGHT, dpi=DPI).astype(float) / 255
    normal = camera_axes(8.0, 0.0) @ [0.0, 1.0, 0.0]
    diffuse, highlight = shading(normal[None])
    expected = np.clip(CLOTH_RGB * diffuse[0] + highlight[0], 0, 1)
    mask = cloth_mask((image * 255).round())
    assert mask.sum() > 500
    near = (np.abs(image[mask] - expected).max(axis=1) < 0.03).mean()
    assert near > 0.9                                              # all but the anti-aliased rim


def test_shading_is_two_sided_and_brightest_towards_the_key_light():
    diffuse, highlight = shading(np.array([KEY_LIGHT, -KEY_LIGHT, [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]))
    assert diffuse[0] == diffuse[1] == diffuse.max()                  # front and back alike
    assert diffuse[0] > diffuse[2] > diffuse[3] and highlight[3] == 0


def test_value_colors_saturate_at_vmax():
    colours = value_colors(np.array([0.0, 0.5, 1.0, 7.0]), vmax=1.0)
    assert np.allclose(colours[2], colours[3]) and not np.allclose(colours[0], colours[1])


def test_render_panels_writes_the_image_as_png(tmp_path):
    vertices, faces = tube(around=8, along=3)
    panels = [Panel("plain", vertices, faces)]
    path = render_panels(tmp_path / "sub" / "p.png", panels, panel_height=PANEL_HEIGHT, dpi=DPI)
    written = (matplotlib.image.imread(path)[..., :3] * 255).round().astype(np.uint8)
    np.testing.assert_array_equal(written, panels_image(panels, panel_height=PANEL_HEIGHT, dpi=DPI))
    assert not np.allclose(CLOTH_RGB, BODY_RGB)
