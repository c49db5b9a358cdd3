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


def test_smoke_workflow_then_forced_rerun_of_one_stage(workdir):
    run = snakemake(workdir, "results/patch/sim_high.h5")
    assert run.returncode == 0, run.stderr[-3000:]
    out = workdir / "results" / "patch"
    with h5py.File(out / "sim_high.h5") as f:
        assert f["positions"].shape[0] == 8  # the cpu profile's patch frames
        assert np.all(f["harmonic_residual"][()] < 1e-5)
        assert f.attrs["stage"] == "simulate_high"
    scene_mtime = (out / "scene.h5").stat().st_mtime_ns
    low_mtime = (out / "sim_low.h5").stat().st_mtime_ns

    rerun = snakemake(workdir, "results/patch/sim_high.h5", "--forcerun", "simulate_low")
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert "rule simulate_low:" in rerun.stderr and "rule scene:" not in rerun.stderr
    assert (out / "scene.h5").stat().st_mtime_ns == scene_mtime
    assert (out / "sim_low.h5").stat().st_mtime_ns > low_mtime
    assert not list(out.glob(".*.tmp.h5"))

    again = snakemake(workdir, "results/patch/")
    assert again.returncode == 0, again.stderr[-3000:]


def test_bad_config_key_stops_the_workflow_with_its_name(workdir, tmp_path):
    config = yaml.safe_load((workdir / "workflow_config.yaml").read_text())
    config["scenes"]["patch"]["solver"] = {"substepz": 3}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "--configfile", str(bad), "-n", "results/patch/scene.h5")
    assert run.returncode != 0
    assert "unknown key 'substepz' in scenes.patch.solver" in run.stdout + run.stderr
