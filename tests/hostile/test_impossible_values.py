"""Item 9 of issue 13: values that cannot work are refused where they enter, naming the flag or the file. A device
that is no device (`--device gpu7`: a traceback from torch or Warp), coordinates that are finite in float64 but
inf in float32 (once written to operators.h5 as inf), and run sizes past what the stage can do in reasonable time
and memory (`--levels 9` once subdivided for minutes without a word). Settings files: test_settings_files.py."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import h5py
import pytest
import torch

from geometry.loop_subdivision import loop_subdivide
from geometry.shapes import torus
from hostile import ARCH, assert_refused, files_in, run_in_process, run_stage, write_patch_scene
from pipeline import operators, subdivide, train
from pipeline.core.cli import check_device
from pipeline.core.errors import PipelineError
from pipeline.subdivide import subdivision_cost
from pipeline.core.torch_setup import configure_torch
from stage_inputs import grid


@pytest.fixture(scope="module")
def patch(tmp_path_factory) -> Path:
    """settings.json of the patch scene (CPU profile) and the scene.h5 of its first sequence."""
    folder = tmp_path_factory.mktemp("patch")
    write_patch_scene(folder)
    return folder


@pytest.mark.parametrize("device", ["gpu7", "cuda:x", "cpu:0", "CUDA"])
def test_simulate_refuses_a_device_that_is_no_device(patch, tmp_path, device):
    before = files_in(tmp_path)
    run = run_stage("simulate", "low", patch / "settings.json", patch / "scene.h5", tmp_path / "sim_low.h5",
                    "--device", device, "--quiet")
    assert_refused(run, f"device '{device}'", "cpu, cuda or cuda:N", folder=tmp_path, before=before)


def test_train_refuses_a_device_that_is_no_device(valid, tmp_path, capsys):
    before = files_in(tmp_path)
    run = run_in_process(train.main, valid / "dataset.h5", valid / "operators.h5", tmp_path / "model.pt",
                         tmp_path / "train.h5", *ARCH, "--epochs", "1", "--device", "gpu7", "--quiet", capsys=capsys)
    assert_refused(run, "device 'gpu7'", folder=tmp_path, before=before)


def test_a_cuda_device_beyond_those_torch_sees_is_refused():
    beyond = f"cuda:{torch.cuda.device_count()}"
    with pytest.raises(PipelineError, match=f"device '{beyond}' requested but torch finds"):
        configure_torch(beyond, seed=0)


def test_a_graphed_training_on_a_device_that_is_not_cuda_is_refused():
    """train and multi share this check: training.cuda_graph on the CPU is one clear error, not a crash later."""
    with pytest.raises(PipelineError, match="training.cuda_graph\\) needs a CUDA device, not 'cpu'"):
        configure_torch("cpu", seed=0, cuda_graph=True)
    assert configure_torch("cpu", seed=0).type == "cpu"


def test_cuda_devices_are_checked_against_the_count():
    count = lambda: 2     # noqa: E731  (two GPUs, whatever this machine has)
    for device in ("cpu", "cuda", "cuda:0", "cuda:1"):
        check_device(device, "Warp", count)
    for device, words in (("cuda:2", "requested but Warp finds 2 CUDA device(s) (--device cuda:0 .. cuda:1)"),
                          ("cuda:-1", "is not cpu, cuda or cuda:N"), ("cuda:", "is not cpu, cuda or cuda:N"),
                          (" cpu", "is not cpu, cuda or cuda:N")):
        with pytest.raises(PipelineError, match=re.escape(f"device '{device}' {words}")):
            check_device(device, "Warp", count)
    with pytest.raises(PipelineError, match=re.escape("Warp finds 0 CUDA device(s) (--device cpu)")):
        check_device("cuda", "Warp", lambda: 0)


def test_mesh_coordinates_beyond_float32_are_refused(tmp_path, capsys):
    """1e39 is finite in float64: the mesh passed validation and became inf in operators.h5 (float32)."""
    mesh = tmp_path / "huge.obj"
    mesh.write_text("v 0 0 0\nv 1e39 0 0\nv 0 1e39 0\nf 1 2 3\n")
    before = files_in(tmp_path)
    for main, flags in ((operators.main, ["--levels", "1", "--conv", "RC7"]), (subdivide.main, ["--levels", "1"])):
        run = run_in_process(main, mesh, tmp_path / "out.h5", *flags, "--quiet", capsys=capsys)
        assert_refused(run, str(mesh), "vertex 1", "float32", folder=tmp_path, before=before)


def test_artifact_values_beyond_float32_are_refused(patch, tmp_path):
    """scene.h5 stores the rest mesh in float64; the solver computes in float32."""
    spoiled = tmp_path / "inputs" / "scene.h5"
    spoiled.parent.mkdir()
    shutil.copy(patch / "scene.h5", spoiled)
    with h5py.File(spoiled, "r+") as f:
        f["rest/vertices"][1, 0] = 1e39
    out = tmp_path / "out"
    run = run_stage("simulate", "low", patch / "settings.json", spoiled, out / "sim_low.h5", "--quiet")
    assert_refused(run, str(spoiled), "'rest/vertices'", "float32")
    assert not out.exists()


def _sheet_obj(folder: Path) -> Path:
    """A 5 x 5 sheet (25 vertices, 32 faces) as an OBJ file."""
    vertices, faces = grid(5)
    mesh = folder / "sheet.obj"
    mesh.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices) +
                    "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    return mesh


def test_subdividing_past_the_ceiling_is_refused_up_front(tmp_path):
    """Nine levels of a 5 x 5 sheet make a million vertices and a harmonic basis of terabytes: once this ran for
    hours without a word; now it stops at once, naming the flag (the timeout would catch the old behaviour)."""
    mesh = _sheet_obj(tmp_path)
    before = files_in(tmp_path)
    run = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "9", timeout=60)
    assert_refused(run, "--levels 9", "vertices (at most 1,000,000)", folder=tmp_path, before=before)
    run = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "6", "--vertices-per-harmonic", "1",
                    timeout=60)
    assert_refused(run, "--levels 6 --vertices-per-harmonic 1", "66,049 harmonics of 66,049 vertices", "GiB",
                   folder=tmp_path, before=before)


def test_subdivide_says_what_it_will_cost(tmp_path):
    mesh = _sheet_obj(tmp_path)
    run = run_stage("subdivide", mesh, tmp_path / "subdiv.h5", "--levels", "2", "--vertices-per-harmonic", "40")
    assert run.returncode == 0, run.stderr
    with h5py.File(tmp_path / "subdiv.h5") as f:
        n_high, n_harmonics = len(f["vertices"]), f["harmonics/basis"].shape[1]
    assert f"Loop x2 of 25 vertices: {n_high:,} vertices, {n_harmonics:,} harmonics: about" in run.stderr


@pytest.mark.parametrize("shape", ["open sheet", "closed torus"])
def test_the_cost_model_counts_the_vertices_loop_subdivision_makes(shape):
    vertices, faces = grid(6) if shape == "open sheet" else torus(8, 5)
    for levels in range(4):
        S, _ = loop_subdivide(vertices, faces, levels)
        assert subdivision_cost(len(vertices), faces, levels, 40).vertices == S.shape[0]


def test_operators_refuse_levels_past_the_ceiling(valid, tmp_path, capsys):
    """31 pooling steps once ran on, repeating the last level of a collapsed mesh."""
    before = files_in(tmp_path)
    run = run_in_process(operators.main, valid / "subdiv.h5", tmp_path / "operators.h5", "--levels", "31",
                         "--conv", "RC7", "--quiet", capsys=capsys)
    assert_refused(run, "--levels must be >= 0 and <= 30, got 31", folder=tmp_path, before=before)
