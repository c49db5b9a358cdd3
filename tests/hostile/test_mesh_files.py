"""Item 8 of issue 13: a mesh file's vertices keep the file's order and count. trimesh drops a vertex that no
face uses and splits vertices along texture seams, renumbering the rest; the OBJ reader keeps vertex i as the
file's i-th `v` line, and validation refuses an unused vertex instead of losing it."""
from __future__ import annotations

import numpy as np
import trimesh

from hostile import assert_refused, files_in, run_stage
from pipeline.core.meshio import load_mesh

# Two triangles of a unit square with a vertex no face uses in the middle of the list.
UNUSED_IN_THE_MIDDLE = """v 0 0 0
v 1 0 0
v 9 9 9
v 0 1 0
v 1 1 0
f 1 2 4
f 2 5 4
"""

# The same square as one quad with texture coordinates that differ per face corner (a UV seam), normals,
# comments, a group and negative (relative) indices.
QUAD_WITH_SEAM = """# exported by hand
o square
v 0 0 0
v 1 0 0
v 0 1 0
v 1 1 0
vt 0 0
vt 1 0
vt 0 1
vt 1 1
vt 0.5 0.5
vn 0 0 1
g cloth
usemtl linen
f -4/1/1 -3/5/1 -1/4/1 -2/3/1
"""


def test_unused_vertex_in_the_middle_is_refused_not_dropped(tmp_path):
    mesh = tmp_path / "square.obj"
    mesh.write_text(UNUSED_IN_THE_MIDDLE)
    assert len(trimesh.load(mesh, process=False, force="mesh").vertices) == 4     # what trimesh makes of it
    before = files_in(tmp_path)
    run = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "1")
    assert_refused(run, str(mesh), "vertex 2", "no face", folder=tmp_path, before=before)


def test_vertices_keep_the_file_order_across_texture_seams(tmp_path):
    mesh = tmp_path / "quad.obj"
    mesh.write_text(QUAD_WITH_SEAM)
    vertices, faces = load_mesh(mesh)
    np.testing.assert_array_equal(vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(faces, [[0, 1, 3], [0, 3, 2]])                 # the quad, fanned from its first corner


def test_unreadable_obj_line_is_one_clear_error(tmp_path):
    mesh = tmp_path / "bad.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n")
    before = files_in(tmp_path)
    run = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "1")
    assert_refused(run, str(mesh), "line 3", folder=tmp_path, before=before)
