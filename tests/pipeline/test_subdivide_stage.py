"""The `subdivide` stage CLI end to end: datasets of subdiv.h5, and clean failures on bad meshes."""
import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from geometry.loop_subdivision import loop_subdivide
from pipeline.core.config import load_config, resolve_scene, write_settings
from pipeline.core.h5 import config_of, read_csr

REPO = Path(__file__).resolve().parents[2]


def run_stage(*args):
    return subprocess.run([sys.executable, "-m", "pipeline.subdivide", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True, timeout=120)


def cloth_patch():
    """A bumpy 6×4 quad patch (35 vertices): open, like the paper's garments."""
    i, j = np.meshgrid(np.arange(7), np.arange(5), indexing="ij")
    vertices = np.stack([0.08 * i, 0.02 * np.sin(i + 2 * j), 0.08 * j], axis=-1).reshape(-1, 3)
    a = (i[:-1, :-1] * 5 + j[:-1, :-1]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + 6], 1), np.stack([a, a + 6, a + 5], 1)])
    return vertices, faces


def test_writes_subdivision_and_harmonics(tmp_path):
    vertices, faces = cloth_patch()
    mesh_path, out = tmp_path / "cloth.obj", tmp_path / "subdiv.h5"
    trimesh.Trimesh(vertices, faces, process=False).export(mesh_path)
    result = run_stage(mesh_path, out, "--quiet")
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""  # --quiet: no progress bar

    expected_s, expected_faces = loop_subdivide(vertices, faces, 2)
    n_high = expected_s.shape[0]
    n_harmonics = math.ceil(n_high / 40)
    with h5py.File(out, "r") as f:
        assert f.attrs["stage"] == "subdivide" and config_of(f)["levels"] == 2
        assert config_of(f)["vertices_per_harmonic"] == f.attrs["vertices_per_harmonic"] == 40
        assert (f.attrs["levels"], f.attrs["n_low_vertices"], f.attrs["n_high_vertices"], f.attrs["n_harmonics"]) \
            == (2, len(vertices), n_high, n_harmonics)
        subdivision = read_csr(f, "S")
        assert subdivision.shape == (n_high, len(vertices))
        assert abs(subdivision - expected_s).max() < 1e-15
        high_vertices, high_faces = f["vertices"][()], f["faces"][()]
        assert high_vertices.dtype == np.float64 and high_faces.dtype == np.int32
        np.testing.assert_array_equal(high_faces, expected_faces)
        np.testing.assert_allclose(high_vertices, subdivision @ vertices, atol=1e-7)  # OBJ text rounding
        harmonics = f["harmonics"]
        assert harmonics.attrs["laplacian"] == "cotangent" and harmonics.attrs["mass"] == "barycentric lumped"
        basis, eigenvalues, mass = (harmonics[name][()] for name in ("basis", "eigenvalues", "mass"))
    assert basis.shape == (n_high, n_harmonics) and eigenvalues.shape == (n_harmonics,) and mass.shape == (n_high,)
    assert abs(eigenvalues[0]) < 1e-8 and np.all(np.diff(eigenvalues) >= 0)
    np.testing.assert_allclose(basis.T @ (mass[:, None] * basis), np.eye(n_harmonics), atol=1e-8)
    np.testing.assert_allclose(mass.sum(), trimesh.Trimesh(high_vertices, high_faces).area, rtol=1e-12)


def test_reads_rest_mesh_of_a_scene_artifact(tmp_path):
    vertices, faces = cloth_patch()
    scene, out = tmp_path / "scene.h5", tmp_path / "subdiv.h5"
    with h5py.File(scene, "w") as f:
        f["rest/vertices"], f["rest/faces"] = vertices, faces.astype(np.int32)
    result = run_stage(scene, out, "--levels", "1", "--vertices-per-harmonic", "20")
    assert result.returncode == 0, result.stderr
    assert "subdivide" in result.stderr  # tqdm progress without --quiet
    expected_s, _ = loop_subdivide(vertices, faces, 1)
    with h5py.File(out, "r") as f:
        assert f.attrs["levels"] == 1 and f.attrs["vertices_per_harmonic"] == 20
        assert f.attrs["n_harmonics"] == math.ceil(expected_s.shape[0] / 20) == f["harmonics/basis"].shape[1]
        np.testing.assert_allclose(f["vertices"][()], expected_s @ vertices, rtol=0, atol=1e-15)


NAN_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 1 0\nf 1 2 3\nf 2 4 3\n"
# Three triangles on the edge 1-2: not a surface.
BOOK_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n"


@pytest.mark.parametrize("content, problem", [(NAN_OBJ, "NaN"), (BOOK_OBJ, "non-manifold"), (None, "does not exist")],
                         ids=["nan-vertex", "non-manifold", "missing"])
def test_bad_input_fails_cleanly(tmp_path, content, problem):
    mesh_path, out = tmp_path / "bad.obj", tmp_path / "out" / "subdiv.h5"
    if content is not None:
        mesh_path.write_text(content)
    result = run_stage(mesh_path, out)  # without --quiet: still nothing but the error line
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {mesh_path}: ") and problem in lines[0]
    assert not out.exists() and not (out.parent.exists() and any(out.parent.iterdir()))


def test_too_many_harmonics_fails_cleanly(tmp_path):
    mesh_path, out = tmp_path / "cloth.obj", tmp_path / "subdiv.h5"
    trimesh.Trimesh(*cloth_patch(), process=False).export(mesh_path)
    result = run_stage(mesh_path, out, "--vertices-per-harmonic", "1", "--quiet")  # K = V: one too many
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {mesh_path}: ") and "--vertices-per-harmonic" in lines[0]
    assert not out.exists()


def test_settings_give_levels_and_harmonics_and_a_flag_overrides(tmp_path):
    mesh_path = tmp_path / "cloth.obj"
    trimesh.Trimesh(*cloth_patch(), process=False).export(mesh_path)
    settings = resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch")
    settings["high_res"].update(subdivision_levels=1, vertices_per_harmonic=20)
    write_settings(settings, tmp_path / "settings.json")
    for out, flags in (("a.h5", []), ("b.h5", ["--vertices-per-harmonic", "30"])):
        result = run_stage(mesh_path, tmp_path / out, "--settings", tmp_path / "settings.json", *flags, "--quiet")
        assert result.returncode == 0, result.stderr
    with h5py.File(tmp_path / "a.h5") as a, h5py.File(tmp_path / "b.h5") as b:
        assert config_of(a) == {"mesh": str(mesh_path), "levels": 1, "vertices_per_harmonic": 20}
        assert (b.attrs["levels"], b.attrs["vertices_per_harmonic"]) == (1, 30)


@pytest.mark.parametrize("content, problem", [(None, "settings file does not exist"), ("[1, 2", "not valid JSON"),
                                              ("{}", "missing setting 'high_res'")],
                         ids=["missing", "not-json", "no-key"])
def test_bad_settings_fail_cleanly(tmp_path, content, problem):
    mesh_path, settings, out = tmp_path / "cloth.obj", tmp_path / "settings.json", tmp_path / "subdiv.h5"
    trimesh.Trimesh(*cloth_patch(), process=False).export(mesh_path)
    if content is not None:
        settings.write_text(content)
    result = run_stage(mesh_path, out, "--settings", settings)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {settings}: ") and problem in lines[0]
    assert not out.exists()
