"""The Snakemake workflow end to end on the CI smoke scene, a forced rerun of one stage, config errors, and the
shape of the wiring: a bare `snakemake` plans the default scene, every job has a log, a benchmark and resources,
and no config value reaches a shell command.

The Snakefile runs from a folder that holds nothing of the project (`--directory`): it finds its config and
schema beside itself, and its jobs import the installed project (`pip install -e .`, done by `make test`).
"""
import re
import shlex
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
SNAKEMAKE = Path(sys.executable).parent / "snakemake"
CONFIG = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
STAGES = {"settings", "scene", "subdivide", "simulate_low", "simulate_high", "operators", "dataset", "train",
          "evaluate"}
ON_DEVICE = {"simulate_low", "simulate_high", "train", "evaluate"}   # the jobs that run on the scene's device


def snakemake(workdir, *args):
    return subprocess.run([str(SNAKEMAKE), "--cores", "2", "--snakefile", str(REPO / "Snakefile"),
                           "--directory", str(workdir), *args], capture_output=True, text=True)


def tail(run):
    """What a failed run said: Snakemake logs on stderr, a stage's own messages come through `tee` on stdout."""
    return run.stdout[-2000:] + run.stderr[-3000:]


def planned_jobs(run) -> dict[str, dict[str, str]]:
    """The jobs of a dry run (`-n -p`): rule name -> its printed fields (log, benchmark, resources, shell...)."""
    jobs, current = {}, None
    for line in run.stdout.splitlines():
        if line.startswith("rule "):
            current = jobs.setdefault(line[len("rule "):].rstrip(":"), {})
        elif current is not None and line.startswith("Shell command: "):
            current["shell"] = line[len("Shell command: "):]
        elif current is not None and re.match(r"    \w+: ", line):
            key, value = line.strip().split(": ", 1)
            current[key] = value
    return jobs


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("workflow")


PRODUCTS = ("settings.json", "scene.h5", "subdiv.h5", "sim_low.h5", "sim_high.h5", "operators.h5", "dataset.h5",
            "model.pt", "train.h5", "eval.h5", "report.md")


def test_smoke_workflow_builds_everything_then_one_stage_reruns_alone(workdir):
    run = snakemake(workdir, "results/patch/")
    assert run.returncode == 0, tail(run)
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
    assert rerun.returncode == 0, tail(rerun)
    assert "rule evaluate:" in rerun.stderr and "rule train:" not in rerun.stderr
    changed = {name for name in PRODUCTS if (out / name).stat().st_mtime_ns != mtimes[name]}
    assert changed == {"eval.h5", "report.md"}

    low = snakemake(workdir, "results/patch/sim_low.h5", "--forcerun", "simulate_low")
    assert low.returncode == 0, tail(low)
    assert "rule simulate_low:" in low.stderr and "rule scene:" not in low.stderr
    assert (out / "scene.h5").stat().st_mtime_ns == mtimes["scene.h5"]
    assert (out / "sim_low.h5").stat().st_mtime_ns > mtimes["sim_low.h5"]


def test_bad_config_key_stops_the_workflow_with_its_name(workdir, tmp_path):
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["scenes"]["patch"]["solver"] = {"substepz": 3}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "--configfile", str(bad), "-n", "results/patch/scene.h5")
    assert run.returncode != 0
    assert "unknown key 'substepz' in scenes.patch.solver" in run.stdout + run.stderr


def test_tiny_garment_scene_runs_end_to_end_with_a_held_out_motion(workdir, tmp_path):
    """pants on the moving mannequin, shrunk to seconds: body and self collision, torso frame, held-out clip,
    renders with the body. The default `make run` is the same chain at full CPU-profile size."""
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["pants"] = {
        "frames": 48, "mesh": {"max_edge": 0.25},
        "drivers": {"mannequin": {"settle_frames": 3, "blend_frames": 5}},
        "solver": {"substeps": 2, "iterations": 10}, "high_res": {"subdivision_levels": 1},
        "training": {"epochs": 1}, "evaluation": {"render_frames": 2, "export_frames": 2, "timing_frames": 2}}
    tiny = tmp_path / "tiny.yaml"
    tiny.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "results/pants/", "--configfile", str(tiny))
    assert run.returncode == 0, tail(run)
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


def test_bare_snakemake_plans_the_default_scene_and_every_job_has_log_benchmark_and_resources(tmp_path):
    run = snakemake(tmp_path, "-n", "-p")
    assert run.returncode == 0, tail(run)
    jobs = planned_jobs(run)
    assert set(jobs) == STAGES | {"all"}
    scene = CONFIG["default_scene"]
    assert all(job["wildcards"] == f"scene={scene}" for name, job in jobs.items() if name != "all")
    for name in STAGES:
        job = jobs[name]
        assert job["log"] == f"results/{scene}/logs/{name}.log"
        assert job["benchmark"] == f"results/{scene}/benchmarks/{name}.tsv"
        assert "mem_mb=" in job["resources"] and "gpu=1" not in job["resources"]   # the cpu profile: no GPU
        assert name == "settings" or job["shell"].endswith(f" 2>&1 | tee {job['log']}")
    assert jobs["train"]["threads"] == jobs["evaluate"]["threads"] == "2"             # --cores 2

    other = snakemake(tmp_path, "-n", "--config", "default_scene=patch", "device=cuda:0")
    assert other.returncode == 0, tail(other)
    jobs = planned_jobs(other)
    assert set(jobs) == STAGES | {"all"}
    assert all(job["wildcards"] == "scene=patch" for name, job in jobs.items() if name != "all")
    assert {name for name, job in jobs.items() if "gpu=1" in job.get("resources", "")} == ON_DEVICE


def test_no_config_value_reaches_a_shell_command(tmp_path):
    """Stages get file paths, --settings, --threads and --quiet only: a config value written into a shell string
    would be run by the shell (here: a quote and a command substitution in the architecture)."""
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["patch"]["network"] = {"arch": "D62' $(touch pwned) 'D8"}
    evil = tmp_path / "evil.yaml"
    evil.write_text(yaml.safe_dump(config))
    run = snakemake(tmp_path, "--configfile", str(evil), "-n", "-p", "results/patch/")
    assert run.returncode == 0, tail(run)
    assert "pwned" not in run.stdout + run.stderr and not (tmp_path / "pwned").exists()
    shells = {name: job["shell"] for name, job in planned_jobs(run).items() if job.get("shell", "None") != "None"}
    assert set(shells) == STAGES - {"settings"}
    words = {"-m", "low", "high", "2>&1", "|", "tee", "--settings", "--scene", "--renders", "--export", "--threads",
             "2", "--quiet"}
    for name, command in shells.items():
        python, *rest = shlex.split(command)
        assert Path(python).resolve() == Path(sys.executable).resolve()    # Snakemake's own interpreter
        stage = f"pipeline.{name.removesuffix('_low').removesuffix('_high')}"
        unexpected = [word for word in rest if word not in words and word != stage
                      and not word.startswith("results/patch/")]
        assert not unexpected, f"{name}: {unexpected} in {command}"
