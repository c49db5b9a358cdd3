"""The viz package: shading, error colours, PNG panels and the GLB comparison scene."""
from __future__ import annotations

import matplotlib.image
import numpy as np
import trimesh

from model_meshes import grid_mesh
from viz.export import write_glb
from viz.render import LIGHT, Panel, face_shading, render_panels, value_colors


def test_shading_is_two_sided_lambert():
    towards = np.cross([1.0, 0, 0], LIGHT)                      # a triangle whose normal is LIGHT
    towards /= np.linalg.norm(towards)
    other = np.cross(LIGHT, towards)
    facing = np.array([[0.0, 0, 0], towards, other])
    assert np.allclose(face_shading(facing, np.array([[0, 1, 2], [0, 2, 1]])), 1.0)   # front and back alike
    edge_on = np.array([[0.0, 0, 0], LIGHT, towards])
    assert np.allclose(face_shading(edge_on, np.array([[0, 1, 2]])), 0.3)


def test_value_colors_saturate_at_vmax():
    colours = value_colors(np.array([0.0, 0.5, 1.0, 7.0]), vmax=1.0)
    assert np.allclose(colours[2], colours[3]) and not np.allclose(colours[0], colours[1])


def test_render_panels_writes_a_png_with_colour_where_values_are(tmp_path):
    vertices, faces = grid_mesh(8, 8)
    path = render_panels(tmp_path / "sub" / "p.png", [Panel("plain", vertices, faces),
                                                       Panel("hot", vertices, faces, np.ones(len(vertices)))],
                         vmax=1.0)
    image = matplotlib.image.imread(path)
    width = image.shape[1]
    assert image.shape[0] > 100 and width >= 2 * image.shape[0]
    left, right = image[:, : int(0.4 * width), :3], image[:, int(0.47 * width): int(0.87 * width), :3]
    saturation = lambda part: (part.max(axis=2) - part.min(axis=2)).max()  # noqa: E731
    assert saturation(right) > saturation(left) + 0.3            # the coloured panel is vivid, the plain one grey-blue


def test_glb_lays_meshes_side_by_side(tmp_path):
    vertices, faces = grid_mesh(4, 5)
    path = write_glb(tmp_path / "c.glb", [("a", vertices, faces, None),
                                          ("b", vertices, faces, np.tile([1.0, 0, 0, 1], (len(vertices), 1)))])
    scene = trimesh.load(path)
    a, b = (scene.geometry[n].vertices for n in ("a", "b"))
    assert a[:, 0].max() < b[:, 0].min()                       # no overlap
    np.testing.assert_allclose(b - b.min(axis=0), vertices - vertices.min(axis=0), atol=1e-6)   # same shape
    assert np.array_equal(scene.geometry["b"].visual.vertex_colors[0, :3], [255, 0, 0])
