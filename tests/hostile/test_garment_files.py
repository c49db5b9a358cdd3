"""Issue 38: a garment file that cannot be dressed stops the dress stage with one `error:` line naming the file
and saying what to set, and leaves nothing behind: no garment at all, wrong units, a non-manifold mesh, panels
that were never sewn, a garment too small for the body."""
from __future__ import annotations

import numpy as np
import pytest

from garment_files import write_garment_obj
from geometry.mesh import edge_faces
from geometry.shapes import cube_sphere
from hostile import REPO, assert_refused, files_in, run_in_process, run_stage
from pipeline import dress
from pipeline.core.config import load_config, resolve_scene, shared_settings, write_settings
from scenes.garments import make_garment


def write_scene_settings(folder, garment: str, **mesh) -> None:
    config = load_config(REPO / "workflow_config.yaml")
    config["scenes"]["mine"] = {"like": "pants", "mesh": {
        "generator": "garment_file", "file": str(folder / garment), "units": "auto", "up": "auto", "weld": 0.0,
        "max_edge": 0.16, "remesh": False, "pins": "auto",
        "fit": {"anchor": "auto", "offset": [0, 0, 0], "scale": 1.0, "settle_frames": 8}, **mesh}}
    write_settings(shared_settings(resolve_scene(config, "mine", "cpu")), folder / "settings.json")


def write_obj(path, vertices, faces) -> None:
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))


def refused(folder, capsys, *words) -> None:
    before = files_in(folder)
    run = run_in_process(dress.main, folder / "settings.json", folder / "dressed.h5", capsys=capsys)
    assert_refused(run, *words, folder=folder, before=before)


def test_a_closed_surface_is_no_garment(tmp_path, capsys):
    write_obj(tmp_path / "ball.obj", *cube_sphere(4, 0.3))
    write_scene_settings(tmp_path, "ball.obj")
    refused(tmp_path, capsys, "ball.obj", "closed surface", "not a garment")


@pytest.mark.parametrize("units, words", [("m", ("wrong units", "mesh.units")), ("auto", ())])
def test_wrong_units_are_refused_and_right_ones_read(tmp_path, capsys, units, words):
    write_garment_obj(tmp_path / "pants.obj", "pants", 0.16, units="cm")
    write_scene_settings(tmp_path, "pants.obj", units=units)
    if words:
        refused(tmp_path, capsys, "pants.obj", *words)
    else:    # the stage's own run, to the end: what it prints
        run = run_stage("dress", tmp_path / "settings.json", tmp_path / "dressed.h5")
        assert run.returncode == 0, run.stderr[-3000:]
        assert (tmp_path / "dressed.h5").is_file()


def test_a_non_manifold_mesh_is_refused(tmp_path, capsys):
    worn = write_garment_obj(tmp_path / "pants.obj", "pants", 0.16, units="cm", panels=False, band_group=False)
    # A fin: a new vertex and a face on an edge that two faces share already.
    edges, sides = edge_faces(make_garment("pants", max_edge=0.16).faces)
    a, b = edges[np.argmax(sides[:, 1] >= 0)] + 1
    text = (tmp_path / "pants.obj").read_text()
    (tmp_path / "pants.obj").write_text(text + f"v 0 120 0\nf {a} {b} {len(worn) + 1}\n")
    write_scene_settings(tmp_path, "pants.obj")
    refused(tmp_path, capsys, "pants.obj", "non-manifold")


def test_panels_never_sewn_are_refused_with_the_weld_to_set(tmp_path, capsys):
    write_garment_obj(tmp_path / "pants.obj", "pants", 0.16, units="cm", seam_gap=0.002)
    write_scene_settings(tmp_path, "pants.obj")
    refused(tmp_path, capsys, "pants.obj", "separate pieces", "mesh.weld")


def test_a_garment_too_small_for_the_body_is_refused_with_the_scale_to_set(tmp_path, capsys):
    write_garment_obj(tmp_path / "pants.obj", "pants", 0.16, units="cm")
    write_scene_settings(tmp_path, "pants.obj", fit={"anchor": "waist", "offset": [0, 0, 0], "scale": 0.5,
                                                     "settle_frames": 8})
    refused(tmp_path, capsys, "pants.obj", "mesh.fit.scale")
