"""The Snakemake workflow end to end on the CI smoke scene, a forced rerun of one stage, and config errors."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
SNAKEMAKE = Path(sys.executable).parent / "snakemake"


def snakemake(workdir, *args):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([str(SNAKEMAKE), "--cores", "2", "--snakefile", str(REPO / "Snakefile"),
                           "--directory", str(workdir), *args], capture_output=True, text=True, env=env)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    work = tmp_path_factory.mktemp("workflow")
    shutil.copy(REPO / "workflow_config.yaml", work)
    (work / "workflow").mkdir()
    shutil.copy(REPO / "workflow" / "config.schema.yaml", work / "workflow")
    return work


PRODUCTS = ("settings.json", "scene.h5", "subdiv.h5", "sim_low.h5", "sim_high.h5", "operators.h5", "dataset.h5",
            "model.pt", "train.h5", "eval.h5", "report.md")


def test_smoke_workflow_builds_everything_then_one_stage_reruns_alone(workdir):
    run = snakemake(workdir, "results/patch/")
    assert run.returncode == 0, run.stderr[-3000:]
    out = workdir / "results" / "patch"
    assert all((out / name).is_file() for name in PRODUCTS), sorted(p.name for p in out.iterdir())
    with h5py.File(out / "sim_high.h5") as f:
        assert f["positions"].shape[0] == 8  # the cpu profile's patch frames
        assert np.all(f["harmonic_residual"][()] < 1e-5)
        assert f.attrs["stage"] == "simulate_high"
    with h5py.File(out / "operators.h5") as f:
        assert "conv/RC9" in f["levels/0"]   # the cpu profile's network.conv
    with h5py.File(out / "eval.h5") as f:
        assert np.isfinite(f["errors/network/test/l1"][()]) and f["errors/predictor/test/l1"][()] > 0
    report = (out / "report.md").read_text()
    assert "## Errors" in report and "ms per frame" in report
    assert list((out / "renders").glob("*.png")) and list((out / "export" / "predicted_obj").glob("*.obj"))
    assert not list(out.glob(".*.tmp.h5")) and not list(out.glob("*.ckpt"))
    mtimes = {name: (out / name).stat().st_mtime_ns for name in PRODUCTS}

    rerun = snakemake(workdir, "results/patch/", "--forcerun", "evaluate")
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert "rule evaluate:" in rerun.stderr and "rule train:" not in rerun.stderr
    changed = {name for name in PRODUCTS if (out / name).stat().st_mtime_ns != mtimes[name]}
    assert changed == {"eval.h5", "report.md"}

    low = snakemake(workdir, "results/patch/sim_low.h5", "--forcerun", "simulate_low")
    assert low.returncode == 0, low.stderr[-3000:]
    assert "rule simulate_low:" in low.stderr and "rule scene:" not in low.stderr
    assert (out / "scene.h5").stat().st_mtime_ns == mtimes["scene.h5"]
    assert (out / "sim_low.h5").stat().st_mtime_ns > mtimes["sim_low.h5"]


def test_bad_config_key_stops_the_workflow_with_its_name(workdir, tmp_path):
    config = yaml.safe_load((workdir / "workflow_config.yaml").read_text())
    config["scenes"]["patch"]["solver"] = {"substepz": 3}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "--configfile", str(bad), "-n", "results/patch/scene.h5")
    assert run.returncode != 0
    assert "unknown key 'substepz' in scenes.patch.solver" in run.stdout + run.stderr


def test_tiny_garment_scene_runs_end_to_end_with_a_held_out_motion(workdir, tmp_path):
    """pants on the moving mannequin, shrunk to seconds: body and self collision, torso frame, held-out clip,
    renders with the body. The default `make run` is the same chain at full CPU-profile size."""
    config = yaml.safe_load((workdir / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["pants"] = {
        "frames": 48, "mesh": {"max_edge": 0.25},
        "drivers": {"mannequin": {"settle_frames": 3, "blend_frames": 5}},
        "solver": {"substeps": 2, "iterations": 10}, "high_res": {"subdivision_levels": 1},
        "training": {"epochs": 1}, "evaluation": {"render_frames": 2, "export_frames": 2, "timing_frames": 2}}
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "results/pants/", "--configfile", str(tiny))
    assert run.returncode == 0, run.stderr[-3000:]
    out = workdir / "results" / "pants"
    with h5py.File(out / "dataset.h5") as f:
        assert f.attrs["frame"] == "torso" and f["split"].attrs["held_out_clips"] == "walk"
        assert len(f["split/held_out"]) == 15 and len(f["split/train"]) + len(f["split/test"]) == 33
    with h5py.File(out / "sim_low.h5") as f, h5py.File(out / "scene.h5") as s:
        x = f["positions"][()]
        assert np.isfinite(x).all()
        np.testing.assert_allclose(x[:, s["pins/ids"][()]], s["pins/targets"][()], atol=1e-5)
    report = (out / "report.md").read_text()
    assert "held-out L1" in report and "never seen in training" in report
    assert len(list((out / "renders").glob("*.png"))) == 2
