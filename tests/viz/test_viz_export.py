"""The GLB comparison scene (moved from tests/model/test_model_viz.py)."""
from __future__ import annotations

import io

import numpy as np
import trimesh

from geometry.shapes import grid_patch
from viz.export import glb_bytes


def test_glb_lays_meshes_side_by_side():
    vertices, faces = grid_patch(4, 5)
    data = glb_bytes([("a", vertices, faces, None),
                      ("b", vertices, faces, np.tile([1.0, 0, 0, 1], (len(vertices), 1)))])
    scene = trimesh.load(io.BytesIO(data), file_type="glb")
    a, b = (scene.geometry[n].vertices for n in ("a", "b"))
    assert a[:, 0].max() < b[:, 0].min()                       # no overlap
    np.testing.assert_allclose(b - b.min(axis=0), vertices - vertices.min(axis=0), atol=1e-6)   # same shape
    assert np.array_equal(scene.geometry["b"].visual.vertex_colors[0, :3], [255, 0, 0])
