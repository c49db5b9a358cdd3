"""A garment from an artist's file (scenes.garment_file, scenes.dressing; issue 38): files the tests write with
the traits of artists' exports (tests/garment_files.py: panels with duplicated seam vertices, one OBJ group each,
centimetres or inches, Z-up, off the origin) are read in metres and Y-up, welded, placed back where the
procedural garment they were made from was worn, and pinned; what cannot be read as a garment is refused with a
message saying what to set."""
from __future__ import annotations

import time

import numpy as np
import pytest

from garment_files import ATTACHMENT_GROUP, write_garment_obj
from geometry.mesh import boundary_loops, cut_along_edges, unique_edges, validate_mesh
from geometry.shapes import cube_sphere, grid_patch
from meshops.rings import boundary_walk
from pipeline.core.meshio import load_mesh_groups
from scenes.dressing import check_encloses, guess_anchor, pin_vertices, place, push_outside
from scenes.garment_file import detect_units, detect_up, garment_from_file, refine_to_edge
from scenes.garments import RestMannequin, make_garment
from scenes.skeleton import default_skeleton

BODY = RestMannequin(default_skeleton())
WELD = 1e-4


def dressed(path, units="auto", up="auto", anchor="auto", scale=1.0, offset=(0.0, 0.0, 0.0), weld=WELD):
    vertices, faces, groups = load_mesh_groups(path)
    garment = garment_from_file(vertices, faces, units, up, weld, None)
    anchor = guess_anchor(garment.vertices, garment.faces, BODY) if anchor == "auto" else anchor
    placed, top = place(garment.vertices, garment.faces, anchor, BODY, scale, np.asarray(offset))
    check_encloses(placed, garment.faces, anchor, top, BODY)
    return garment, anchor, placed, top, groups


@pytest.mark.parametrize("kind, units, up, anchor", [("pants", "cm", "y", "waist"), ("pants", "mm", "z", "waist"),
                                                     ("tshirt", "m", "z", "shoulders"),
                                                     ("skirt", "mm", "y", "waist"), ("dress", "cm", "z", "shoulders")])
def test_a_file_garment_is_read_welded_and_put_back_where_it_was_worn(tmp_path, kind, units, up, anchor):
    path = tmp_path / f"{kind}.obj"
    worn = write_garment_obj(path, kind, 0.16, units=units, up=up, offset=(0.3, 0.5, -0.2))
    garment, guessed, placed, _, _ = dressed(path)
    assert (garment.units, garment.up, guessed) == (units, up, anchor)
    whole = make_garment(kind, max_edge=0.16)
    assert len(garment.vertices) == len(whole.vertices) and len(garment.faces) == len(whole.faces)
    # Every file vertex lands within 1 cm of where the procedural garment it was made from was worn.
    assert np.abs(placed[garment.file_to_mesh] - worn).max() < 0.01


def test_inches_are_asked_for_where_centimetres_fit_too_and_read_when_given(tmp_path):
    path = tmp_path / "shirt.obj"
    worn = write_garment_obj(path, "tshirt", 0.16, units="in", up="z")
    with pytest.raises(ValueError, match="garment's size in cm and in in: set mesh.units"):
        dressed(path)
    garment, _, placed, _, _ = dressed(path, units="in")
    assert np.abs(placed[garment.file_to_mesh] - worn).max() < 0.01


def test_units_and_up_detection_at_their_limits():
    box = lambda *extent: np.array([[0.0, 0.0, 0.0], extent])  # noqa: E731
    assert detect_units(box(0.4, 1.0, 0.3), "auto") == "m"
    assert detect_units(box(40, 100, 30), "auto") == "cm"       # 100 in would be 2.54 m
    assert detect_units(box(400, 1000, 300), "auto") == "mm"
    with pytest.raises(ValueError, match="no garment's size in any unit"):
        detect_units(box(1e5, 1e5, 1e5), "auto")
    with pytest.raises(ValueError, match="wrong units"):
        detect_units(box(40, 100, 30), "m")                     # a 100 m garment
    assert detect_up(box(0.4, 1.0, 0.3), "auto") == "y" and detect_up(box(0.4, 0.3, 1.0), "auto") == "z"
    with pytest.raises(ValueError, match="set mesh.up"):
        detect_up(box(0.5, 0.5, 0.45), "auto")
    assert detect_up(box(0.5, 0.5, 0.45), "z") == "z"


def test_pins_are_the_waistband_a_named_group_or_listed_indices(tmp_path):
    path = tmp_path / "pants.obj"
    write_garment_obj(path, "pants", 0.16, units="cm")
    garment, _, placed, top, groups = dressed(path)
    whole = make_garment("pants", max_edge=0.16)
    auto = pin_vertices("auto", top, groups, garment.file_to_mesh)
    # The welded garment numbers its vertices as the whole one does: the top opening is its waistband.
    np.testing.assert_array_equal(auto, np.sort(whole.attachment))
    band = pin_vertices({"group": ATTACHMENT_GROUP}, top, groups, garment.file_to_mesh)
    assert set(auto) <= set(band) and len(band) < len(garment.vertices) / 2
    np.testing.assert_array_equal(pin_vertices({"indices": [0, 1, 0]}, top, groups, garment.file_to_mesh),
                                  np.unique(garment.file_to_mesh[[0, 1]]))
    with pytest.raises(ValueError, match="no group of the file .*band"):
        pin_vertices({"group": "collar"}, top, groups, garment.file_to_mesh)
    with pytest.raises(ValueError, match="beyond the file's"):
        pin_vertices({"indices": [len(garment.file_to_mesh)]}, top, groups, garment.file_to_mesh)
    # Every pin follows a torso or leg part near it; the waistband follows the pelvis or the spine.
    assert set(BODY.nearest_part(placed[auto]).tolist()) <= {BODY.skel.index("pelvis"), BODY.skel.index("spine")}


def test_panels_whose_seam_copies_lie_apart_are_sewn_by_the_weld_and_refused_without(tmp_path):
    path = tmp_path / "pants.obj"
    worn = write_garment_obj(path, "pants", 0.16, units="cm", seam_gap=0.002)
    with pytest.raises(ValueError, match=r"separate pieces once welded within 0.001 m.*mesh.weld"):
        dressed(path, weld=0.001)
    garment, _, placed, _, _ = dressed(path, weld=0.005)
    assert len(garment.vertices) == len(make_garment("pants", max_edge=0.16).vertices)
    assert np.abs(placed[garment.file_to_mesh] - worn).max() < 0.01


def test_what_is_no_garment_or_cannot_be_simulated_is_refused():
    with pytest.raises(ValueError, match="closed surface"):
        guess_anchor(*cube_sphere(3, 0.3), BODY)
    with pytest.raises(ValueError, match="one opening only.*mesh.fit.anchor"):
        guess_anchor(*grid_patch(4, 4, 0.5, 0.5), BODY)
    vertices, faces = grid_patch(2, 2, 0.5, 0.5)
    fin = np.array([[*unique_edges(faces)[len(faces)], len(vertices)]])   # a third face on an interior edge
    nonmanifold = np.concatenate([faces, fin])
    with pytest.raises(ValueError, match="non-manifold"):
        garment_from_file(np.vstack([vertices, [[0.2, 0.2, 0.3]]]) * [1, 1, 1], nonmanifold, "m", "y", 0.0, None)


def test_a_garment_off_the_body_or_cut_open_does_not_enclose_it(tmp_path):
    path = tmp_path / "pants.obj"
    write_garment_obj(path, "pants", 0.16, units="cm")
    with pytest.raises(ValueError, match="does not go around the body's pelvis.*mesh.fit.offset"):
        dressed(path, offset=(0.6, 0.0, 0.0))
    # A skirt slit open down its front centre (the slit's sides 2 mm apart): one opening, waist, slit and hem.
    skirt = make_garment("skirt", max_edge=0.16)
    edges = unique_edges(skirt.faces)
    front = (np.abs(skirt.vertices[edges, 0]) < 1e-9).all(axis=1) & (skirt.vertices[edges, 2] > 0).all(axis=1)
    vertices, faces, copied = cut_along_edges(skirt.vertices, skirt.faces, edges[front])
    copy = np.r_[False, copied[1:] == copied[:-1]]
    vertices[copy, 0] += 0.002
    with pytest.raises(ValueError, match="one opening only"):
        guess_anchor(vertices, faces, BODY)
    placed, top = place(vertices, faces, "waist", BODY, 1.0, np.zeros(3))
    with pytest.raises(ValueError, match="does not go around the body's pelvis.*cut open"):
        check_encloses(placed, faces, "waist", top, BODY)


def test_boundary_loops_agree_with_the_operators_boundary_walk():
    garment = make_garment("pants", max_edge=0.16)
    vertices, faces = garment.vertices, garment.faces
    loops = boundary_loops(len(vertices), faces)
    following, _ = boundary_walk(len(vertices), faces)
    assert len(loops) == 3 and sum(map(len, loops)) == (following >= 0).sum()
    for loop in loops:
        np.testing.assert_array_equal(following[loop], np.roll(loop, -1))


def test_refining_keeps_the_files_vertices_and_splits_every_edge_below_max_edge():
    garment = make_garment("skirt", max_edge=0.25)
    vertices, faces = refine_to_edge(garment.vertices, garment.faces, 0.06)
    validate_mesh(vertices, faces)
    np.testing.assert_array_equal(vertices[:len(garment.vertices)], garment.vertices)
    edges = unique_edges(faces)
    assert np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).max() < 0.06
    euler = lambda v, f: len(v) - len(unique_edges(f)) + len(f)  # noqa: E731
    assert euler(vertices, faces) == euler(garment.vertices, garment.faces)
    assert len(boundary_loops(len(vertices), faces)) == 2


def test_pins_inside_the_body_are_pushed_out_to_the_clearance():
    inside = BODY.joint("pelvis") + np.array([[0.0, 0.0, 0.05], [0.05, 0.02, -0.03]])
    out = push_outside(inside, BODY, 0.01)
    assert (BODY.distance(inside) < 0).all() and (BODY.distance(out) >= 0.0099).all()


def test_a_garment_of_20k_vertices_is_read_welded_and_placed_in_seconds(tmp_path):
    path = tmp_path / "pants_dense.obj"
    worn = write_garment_obj(path, "pants", 0.0145, units="cm", up="z", offset=(0.1, 0.0, 0.2))
    start = time.perf_counter()
    garment, anchor, placed, _, _ = dressed(path)
    assert len(garment.vertices) > 20_000 and anchor == "waist"
    assert np.abs(placed[garment.file_to_mesh] - worn).max() < 0.01
    assert time.perf_counter() - start < 30    # a guard against a quadratic step, not a benchmark


@pytest.mark.parametrize("suffix", ["ply", "glb"])
def test_a_garment_in_another_format_trimesh_reads_is_dressed_the_same(tmp_path, suffix):
    import trimesh
    whole = make_garment("pants", max_edge=0.16)
    path = tmp_path / f"pants.{suffix}"
    trimesh.Trimesh(whole.vertices * 1000.0, whole.faces, process=False).export(path)
    garment, anchor, placed, _, groups = dressed(path)
    assert (garment.units, anchor, groups) == ("mm", "waist", {})
    # glTF is Y-up by definition and trimesh keeps the file's vertex order for one mesh.
    np.testing.assert_allclose(placed, whole.vertices, atol=1e-6)


def test_refining_to_a_tiny_max_edge_is_refused_before_it_fills_memory():
    garment = make_garment("skirt", max_edge=0.25)
    with pytest.raises(ValueError, match="beyond 2,000,000 faces: raise max_edge"):
        refine_to_edge(garment.vertices, garment.faces, 1e-5)
