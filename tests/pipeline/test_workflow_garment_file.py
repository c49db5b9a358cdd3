"""Issue 38's acceptance: a user's OBJ of trousers (centimetres, off the origin, panels with duplicated seam
vertices) and one of a shirt (Z-up, its panels' seam copies 1 mm apart, pinned by a named group) each go through
the whole chain with one overlay file and one command: `snakemake results/<garment>/ --configfile overlay.yaml`,
at a tiny size. The settled garment is clear of the body in every frame and keeps the file's edge lengths; the
report's errors are finite and the network beats Loop subdivision on the test split."""
from __future__ import annotations

import h5py
import numpy as np
import pytest
import yaml

from garment_files import ATTACHMENT_GROUP, write_garment_obj
from geometry.mesh import unique_edges
from pipeline.artifacts.evaluation import read_errors
from pipeline.core.meshio import load_mesh_groups
from pipeline.dress import EDGE_TOLERANCE
from scenes.capsules import capsule_signed_distance
from scenes.garment_file import garment_from_file
from workflow_runs import build, snakemake, tail, tiny_pants

GARMENTS = {   # scene: (procedural kind it is made from, file traits, its overlay's mesh keys)
    "trousers": ("pants", dict(units="cm", offset=(0.2, 0.4, 0.1)), dict(units="auto", up="auto", weld=0.0)),
    "shirt": ("tshirt", dict(units="m", up="z", seam_gap=0.001), dict(units="m", up="auto", weld=0.004,
                                                                       pins={"group": ATTACHMENT_GROUP})),
}


@pytest.fixture(scope="module")
def garment_build(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("garment_file")
    tiny = tiny_pants(workdir)
    scenes = {}
    for scene, (kind, traits, keys) in GARMENTS.items():
        write_garment_obj(workdir / f"{scene}.obj", kind, 0.25, **traits)
        scenes[scene] = {"like": "pants", "training": {"epochs": 6},
                         "mesh": {"generator": "garment_file", "file": f"{scene}.obj", "max_edge": 0.25,
                                  "remesh": False, "pins": "auto",
                                  "fit": {"anchor": "auto", "offset": [0, 0, 0], "scale": 1.0, "settle_frames": 12},
                                  **keys}}
    (workdir / "overlay.yaml").write_text(yaml.safe_dump({"scenes": scenes}))
    run = build(workdir, *(f"results/{scene}/" for scene in GARMENTS), "--configfile", str(tiny), str(workdir / "overlay.yaml"))
    return workdir, run


@pytest.mark.parametrize("scene", GARMENTS)
def test_a_users_garment_runs_end_to_end_and_the_network_beats_loop_subdivision(garment_build, scene):
    workdir, run = garment_build
    assert run.returncode == 0, tail(run)
    errors = read_errors(workdir / f"results/{scene}/eval.h5")
    assert all(np.isfinite(v) for who in errors.values() for split in who.values() for v in split.values())
    assert errors["network"]["test"]["l1"] < errors["predictor"]["test"]["l1"]
    report = (workdir / f"results/{scene}/report.md").read_text()
    assert f"{scene}.obj" in report and (workdir / f"results/{scene}/report.html").is_file()


@pytest.mark.parametrize("scene", GARMENTS)
def test_the_settled_garment_is_clear_of_the_body_in_every_frame_and_keeps_the_files_edges(garment_build, scene):
    workdir, run = garment_build
    assert run.returncode == 0, tail(run)
    results = workdir / "results" / scene
    with h5py.File(results / "dressed.h5") as f:
        settled = f["vertices"][()]
        assert f.attrs["units"] == GARMENTS[scene][1]["units"] and f.attrs["anchor"] == \
            {"trousers": "waist", "shirt": "shoulders"}[scene]
    vertices, faces, _ = load_mesh_groups(workdir / f"{scene}.obj")
    mesh = GARMENTS[scene][2]
    garment = garment_from_file(vertices, faces, GARMENTS[scene][1]["units"], "auto", mesh["weld"], None)
    edges = unique_edges(garment.faces)
    ratio = (np.linalg.norm(settled[edges[:, 0]] - settled[edges[:, 1]], axis=1)
             / np.linalg.norm(garment.vertices[edges[:, 0]] - garment.vertices[edges[:, 1]], axis=1))
    assert EDGE_TOLERANCE[0] <= ratio.min() and ratio.max() <= EDGE_TOLERANCE[1]
    assert np.abs(ratio - 1).mean() < 0.02
    for sequence in sorted((results / "sequences").iterdir()):
        with h5py.File(sequence / "sim_low.h5") as f:
            positions = f["positions"][()].astype(np.float64)
        with h5py.File(sequence / "scene.h5") as f:
            np.testing.assert_array_equal(f["rest/vertices"][()], settled)
            capsules = [f[f"capsules/{name}"][()] for name in ("a", "b", "radius_a", "radius_b")]
        clearance = [capsule_signed_distance(x, a, b, *capsules[2:]).min()
                     for x, a, b in zip(positions, capsules[0], capsules[1])]
        assert min(clearance) >= 0.0, (sequence.name, np.argmin(clearance), min(clearance))


def test_a_missing_garment_file_is_one_error_before_any_job(tmp_path):
    tiny = tiny_pants(tmp_path)
    (tmp_path / "overlay.yaml").write_text(yaml.safe_dump({"scenes": {"mine": {"like": "pants", "mesh": {
        "generator": "garment_file", "file": "nowhere.obj", "units": "auto", "up": "auto", "weld": 0.0,
        "max_edge": 0.25, "remesh": False, "pins": "auto",
        "fit": {"anchor": "auto", "offset": [0, 0, 0], "scale": 1.0, "settle_frames": 12}}}}}))
    run = snakemake(tmp_path, "-n", "results/mine/", "--configfile", str(tiny), str(tmp_path / "overlay.yaml"))
    errors = [line for line in run.stderr.splitlines() if line.startswith("error: ")]
    assert run.returncode != 0 and errors == [f"error: nowhere.obj: garment file of scene 'mine' (mesh.file) does "
                                              f"not exist (working directory {tmp_path})"], tail(run)
    assert "Traceback" not in run.stderr and not (tmp_path / "results").exists()
