"""The Snakemake workflow end to end on the CI smoke scene, a forced rerun of one stage, config errors, and the
shape of the wiring: a bare `snakemake` plans the default scene, every job has a log, a benchmark and resources,
and no config value reaches a shell command.

The Snakefile runs from a folder that holds nothing of the project (`--directory`): it finds its config and
schema beside itself, and its jobs import the installed project (`pip install -e .`, done by `make test`).
"""
import re
import shlex
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from pipeline import workflow_plan
from workflow_runs import REPO, TINY_FRAMES, planned_counts, planned_jobs, snakemake, tail, tiny_pants

CONFIG = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
SETTINGS_RULES = {"settings", "simulation_settings"}                 # write JSON in Snakemake: no shell command
STAGES = {*SETTINGS_RULES, "scene", "sequence", "subdivide", "simulate_low", "simulate_high", "operators", "dataset",
          "train", "evaluate"}
PER_SEQUENCE = {"sequence", "simulate_low", "simulate_high"}          # one job per sequence of the scene
ON_DEVICE = {"simulate_low", "simulate_high", "train", "evaluate"}   # the jobs that run on the scene's device


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("workflow")


PRODUCTS = ("settings.json", "scene.h5", "subdiv.h5", "sequences/train_000/scene.h5",
            "sequences/train_000/sim_low.h5", "sequences/train_000/sim_high.h5", "operators.h5", "dataset.h5",
            "model.pt", "train.h5", "eval.h5", "report.md")


def test_smoke_workflow_builds_everything_then_one_stage_reruns_alone(workdir, tmp_path):
    run = snakemake(workdir, "results/patch/")
    assert run.returncode == 0, tail(run)
    out = workdir / "results" / "patch"
    assert all((out / name).is_file() for name in PRODUCTS), sorted(p.name for p in out.iterdir())
    assert sorted(p.name for p in (out / "sequences").iterdir()) == ["train_000"]     # a grid has one sequence
    with h5py.File(out / "sequences" / "train_000" / "sim_high.h5") as f:
        assert f["positions"].shape[0] == 8  # the cpu profile's patch frames
        assert np.all(f["harmonic_residual"][()] < 1e-5)
        assert f.attrs["stage"] == "simulate_high"
    with h5py.File(out / "operators.h5") as f:
        assert "conv/RC9" in f["levels/0"]   # the cpu profile's network.conv
    with h5py.File(out / "eval.h5") as f:
        assert np.isfinite(f["errors/network/test/l1"][()]) and f["errors/predictor/test/l1"][()] > 0
    report = (out / "report.md").read_text()
    assert "## Errors" in report and "ms per frame" in report
    assert "](tradeoff/report.md)" in report and "](study/report.md)" in report     # the scene's other reports
    assert "](convs/report.md)" in report
    assert list((out / "renders").glob("*.png")) and list((out / "export" / "predicted_obj").glob("*.obj"))
    assert not list(out.glob(".*.tmp.h5")) and not list(out.glob("*.ckpt"))
    mtimes = {name: (out / name).stat().st_mtime_ns for name in PRODUCTS}

    rerun = snakemake(workdir, "results/patch/", "--forcerun", "evaluate")
    assert rerun.returncode == 0, tail(rerun)
    assert "rule evaluate:" in rerun.stderr and "rule train:" not in rerun.stderr
    changed = {name for name in PRODUCTS if (out / name).stat().st_mtime_ns != mtimes[name]}
    assert changed == {"eval.h5", "report.md"}

    # A training setting changed: training and what follows rerun, no simulation (simulation.json is unchanged);
    # a solver setting changed: the simulation reruns.
    for change, reruns, untouched in (
            ({"training": {"epochs": 3}}, {"settings", "operators", "train", "evaluate"},
             {"simulation_settings", "scene", "sequence", "subdivide", "simulate_low", "simulate_high", "dataset"}),
            ({"solver": {"iterations": 31}}, {"simulation_settings", "simulate_low", "simulate_high", "dataset"},
             set())):
        overlay = tmp_path / "overlay.yaml"
        overlay.write_text(yaml.safe_dump({"profiles": {"cpu": {"scenes": {"patch": change}}}}))
        plan = snakemake(workdir, "-n", "--configfile", str(REPO / "workflow_config.yaml"), str(overlay), "--",
                         "results/patch/")
        assert plan.returncode == 0, tail(plan)
        planned = set(planned_jobs(plan))
        assert reruns <= planned and not planned & untouched, (change, sorted(planned))

    low = snakemake(workdir, "results/patch/sequences/train_000/sim_low.h5", "--forcerun", "simulate_low")
    assert low.returncode == 0, tail(low)
    assert "rule simulate_low:" in low.stderr and "rule scene:" not in low.stderr and "rule sequence:" not in low.stderr
    assert (out / "sequences/train_000/scene.h5").stat().st_mtime_ns == mtimes["sequences/train_000/scene.h5"]
    assert (out / "sequences/train_000/sim_low.h5").stat().st_mtime_ns > mtimes["sequences/train_000/sim_low.h5"]


def test_bad_config_key_stops_the_workflow_with_its_name(workdir, tmp_path):
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["scenes"]["patch"]["solver"] = {"substepz": 3}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "--configfile", str(bad), "-n", "results/patch/scene.h5")
    assert run.returncode != 0
    assert "unknown key 'substepz' in scenes.patch.solver" in run.stdout + run.stderr


def test_tiny_garment_scene_gathers_its_sequences_and_more_sequences_reuse_the_made_ones(tiny_pants_build,
                                                                                          tmp_path):
    """pants on the moving mannequin, shrunk to seconds: two training sequences and the held-out walk, each
    simulated with body and self collision, gathered in the torso frame; renders with the body. The default
    `make run` is the same chain at full CPU-profile size (one job per sequence; here the two training
    sequences are one batch job, `shard: 2`). A third sequence then costs its own jobs and the learning stages,
    nothing else. The build is tests/conftest.py's `tiny_pants_build` (the first run in its folder), which the study
    and trade-off tests build on."""
    run, workdir = tiny_pants_build.run, tiny_pants_build.workdir
    assert run.returncode == 0, tail(run)
    assert "rule simulate_high_batch_pants_000:" in run.stderr and "rule simulate_high:" not in run.stderr
    out = workdir / "results" / "pants"
    assert sorted(p.name for p in (out / "sequences").iterdir()) == ["held_out_000", "train_000", "train_001"]
    with h5py.File(out / "dataset.h5") as f:
        assert f.attrs["frame"] == "torso" and f["split"].attrs["held_out_clips"] == "walk"
        sequence = f["sequence"][()]
        assert [n.decode() for n in f["sequences/names"][()]] == ["train_000", "train_001", "held_out_000"]
        assert np.array_equal(f["split/held_out"][()], np.flatnonzero(sequence == 2))
        assert len(f["split/train"]) + len(f["split/test"]) == np.count_nonzero(sequence < 2)
        assert np.count_nonzero(sequence == 0) == TINY_FRAMES and "capsules/a" in f
    with h5py.File(out / "sequences/train_001/sim_low.h5") as f, \
            h5py.File(out / "sequences/train_001/scene.h5") as s:
        assert f.attrs["batch"] == 2
        x = f["positions"][()]
        assert np.isfinite(x).all()
        np.testing.assert_allclose(x[:, s["pins/ids"][()]], s["pins/targets"][()], atol=1e-5)
    report = (out / "report.md").read_text()
    assert "held-out L1" in report and "never seen in training" in report
    assert len(list((out / "renders").glob("frame_*.png"))) == 2
    assert sorted(p.name for p in (out / "videos").glob("*.mp4")) == ["held_out.mp4", "test.mp4"]
    page = (out / "report.html").read_text()
    assert page.count('<video src="data:video/mp4;base64,') == 2 and "Held-out motion (walk)" in page

    more = snakemake(workdir, "-n", "results/pants/", "--configfile",
                     str(tiny_pants(tmp_path, "more.yaml", 3, shard=2)))
    assert more.returncode == 0, tail(more)
    assert planned_counts(more) == {"sequence": 1, "simulate_low_batch_pants_001": 1,
                                    "simulate_high_batch_pants_001": 1, "dataset": 1, "train": 1, "evaluate": 1,
                                    "results/pants/": 1, "total": 7}
    assert "seq=train_002" in more.stdout


@pytest.mark.parametrize("device, threads", [("cpu", 1), ("cuda:0", 2)])
def test_a_high_res_batch_job_takes_a_thread_a_sequence_on_a_gpu(tmp_path, device, threads):
    """The high-res batch job of two sequences: on a GPU two threads (their harmonic targets and residuals at
    once), passed to the stage; on the CPU one (it steps on one thread for a long time)."""
    run = snakemake(tmp_path, "-n", "-p", "results/pants/sequences/train_000/sim_high.h5", "--configfile",
                    str(tiny_pants(tmp_path, shard=2)), "--config", f"device={device}")
    assert run.returncode == 0, tail(run)
    job = planned_jobs(run)["simulate_high_batch_pants_000"]
    assert job.get("threads", "1") == str(threads) and f" --threads {threads} " in job["shell"]   # 1: not printed


def test_the_plan_states_what_the_runs_and_the_dataset_weigh(tiny_pants_build):
    """Once the mesh is made, the plan's second line says the disk: the runs' positions byte for byte (as the
    files hold them) and a bound on the dataset's frames."""
    workdir = tiny_pants_build.workdir
    assert tiny_pants_build.run.returncode == 0, tail(tiny_pants_build.run)
    run = snakemake(workdir, "-n", "--configfile", str(tiny_pants_build.config), "--", "results/pants/")
    disk = [line for line in run.stderr.splitlines() if line.startswith("disk:")]
    out = workdir / "results" / "pants"
    runs, counts = 0, {}
    for level in ("low", "high"):
        for path in sorted(out.glob(f"sequences/*/sim_{level}.h5")):
            with h5py.File(path) as f:
                runs += f["positions"].nbytes
                counts[level] = f["positions"].shape[1]
    frame = 12 * (counts["low"] + counts["high"])    # float32 positions of both levels
    assert runs % frame == 0
    assert len(disk) == 1 and disk[0].startswith(
        f"disk: pants, {counts['low']:,} -> {counts['high']:,} vertices: {workflow_plan._size(runs)} of runs "
        f"({workflow_plan._size(frame)} a frame of both levels), at most "), run.stderr
    with h5py.File(out / "dataset.h5") as f:
        frames = len(f["sequence"])
        per_frame = []
        f.visititems(lambda name, obj: per_frame.append(obj.nbytes) if isinstance(obj, h5py.Dataset)
                     and obj.shape[:1] == (frames,) else None)
    assert sum(per_frame) / frames <= 12 * sum(counts.values()) + workflow_plan.DATASET_FRAME_EXTRA


def test_a_train_job_of_several_ranks_runs_them_under_torchrun_with_a_gpu_each(tmp_path):
    """training.ranks: 2 on CUDA: the train job asks for two GPUs and runs two processes under torchrun, the job's
    threads shared out between them."""
    overlay = tmp_path / "ranks.yaml"
    overlay.write_text(yaml.safe_dump({"profiles": {"cpu": {"scenes": {"patch": {"training": {"ranks": 2}}}}}}))
    run = snakemake(tmp_path, "-n", "-p", "--configfile", str(REPO / "workflow_config.yaml"), str(overlay),
                    "--config", "device=cuda:0", "--", "results/patch/model.pt")
    assert run.returncode == 0, tail(run)
    job = planned_jobs(run)["train"]
    assert "gpu=2" in job["resources"] and job["threads"] == "2"
    assert " -m torch.distributed.run --standalone --nproc_per_node=2 -m pipeline.train " in job["shell"]
    assert " --threads 1 " in job["shell"]
    # The trade-off's matched networks are the scene's recipe on cheaper inputs: trained on its ranks too; its
    # width networks (their own epochs, a grid) one process each.
    run = snakemake(tmp_path, "-n", "-p", "--configfile", str(REPO / "workflow_config.yaml"), str(overlay),
                    "--config", "device=cuda:0", "--", "results/patch/tradeoff/")
    assert run.returncode == 0, tail(run)
    jobs = planned_jobs(run)
    matched, width = jobs["tradeoff_train_matched"], jobs["tradeoff_train"]
    assert "gpu=2" in matched["resources"] and " --nproc_per_node=2 -m pipeline.train " in matched["shell"]
    assert "gpu=1" in width["resources"] and "torch.distributed.run" not in width["shell"]
    # With two jobs a GPU, the ranks and the trade-off's timing job take their GPUs whole: every slot of each.
    run = snakemake(tmp_path, "-n", "-p", "--configfile", str(REPO / "workflow_config.yaml"), str(overlay),
                    "--config", "device=cuda:0", "gpus=2", "jobs_per_gpu=2", "--", "results/patch/tradeoff/")
    assert run.returncode == 0, tail(run)
    jobs = planned_jobs(run)
    assert ["gpu=4" in jobs[name]["resources"] for name in ("train", "tradeoff_train_matched")] == [True, True]
    assert "gpu=2" in jobs["tradeoff"]["resources"] and "gpu=1" in jobs["tradeoff_evaluate"]["resources"]


@pytest.mark.tiny_pants_target("results/pants/study/", study={"sequence_counts": [1, 2], "train_frames": [10],
                                                               "oracle": True})
def test_the_study_trains_one_network_per_count_and_variant_on_the_first_sequences(tiny_pants_build):
    """`results/pants/study/` on the tiny pants: datasets of the first 1 and 2 training sequences (each with the
    held-out walk), the scene's dataset within 10 frames (one whole sequence) and the oracle, both input variants
    trained on each for the same number of optimiser steps, one table. Built by tests/conftest.py's
    `tiny_pants_build` with the scene (the mark above: the target and its study block)."""
    run, workdir = tiny_pants_build.run, tiny_pants_build.workdir
    assert "results/pants/study/" in tiny_pants_build.targets
    assert run.returncode == 0, tail(run)
    out = workdir / "results" / "pants" / "study"
    with h5py.File(out / "n1" / "dataset.h5") as f:
        assert [n.decode() for n in f["sequences/names"][()]] == ["train_000", "held_out_000"]
    with h5py.File(out / "study.h5") as f:
        assert [v.decode() for v in f["labels"][()]] == ["n1", "n2", "f10", "oracle"]
        assert [v.decode() for v in f["variants"][()]] == ["positions", "body_relative"]
        assert np.isfinite(f["l1/network/held_out"][()]).all()
        frames = f["trained_frames"][()]
    one, two, within, oracle = frames[0]
    assert (frames == frames[0]).all() and one < two and within <= two < oracle    # the oracle adds the walk
    with h5py.File(out / "f10" / "body_relative" / "train.h5") as f:    # one sequence, the steps of two
        assert f.attrs["epochs"] == 2
    epochs = {}
    for n in (1, 2):
        with h5py.File(out / f"n{n}" / "body_relative" / "train.h5") as f:
            epochs[n] = f.attrs["epochs"]
    assert epochs == {1: 2, 2: 1}          # the scene's 1 epoch on 2 sequences: 2 epochs on one
    assert "Loop subdivision alone" in (out / "report.md").read_text()


def test_the_study_step_budget_is_its_own_or_the_scenes(tmp_path):
    """study.epochs sets the grid's steps apart from the scene's own training (null: training.epochs); a network
    on n of S sequences trains epochs x S / n epochs."""
    config = tiny_pants(tmp_path, "budget.yaml", sequences=4)
    overlay = yaml.safe_load(config.read_text())
    pants = overlay["profiles"]["cpu"]["scenes"]["pants"]
    for study_epochs, expected in ((None, {1: 12, 2: 6}), (2, {1: 8, 2: 4})):
        pants["training"] = {"epochs": 3}
        pants["study"] = {"sequence_counts": [1, 2], "epochs": study_epochs}
        config.write_text(yaml.safe_dump(overlay))
        run = snakemake(tmp_path, "-n", "-p", "results/pants/study/", "--configfile", str(config))
        assert run.returncode == 0, tail(run)
        trainings = [line for line in run.stdout.splitlines() if "-m pipeline.train" in line and "/study/n" in line]
        found = {int(re.search(r"/study/n([0-9]+)/", line)[1]): int(re.search(r"--epochs '?([0-9]+)", line)[1])
                 for line in trainings}
        assert found == expected, study_epochs


def test_a_bvh_clip_is_an_input_of_its_sequence_and_a_missing_one_is_named(tmp_path):
    bvh = tmp_path / "walk.bvh"     # read for its header only (its length, planned before any job runs)
    bvh.write_text("HIERARCHY\nROOT hip\n{\n\tOFFSET 0 0 0\n\tCHANNELS 6 Xposition Yposition Zposition Zrotation "
                   "Xrotation Yrotation\n\tEnd Site\n\t{\n\t\tOFFSET 0 1 0\n\t}\n}\nMOTION\nFrames: 2\n"
                   "Frame Time: 0.5\n0 0 0 0 0 0\n0 0 0 0 0 0\n")
    config = tiny_pants(tmp_path, test_clips=[{"bvh": str(bvh), "start": 0.5}])
    run = snakemake(tmp_path, "-n", "-p", "results/pants/", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    inputs = {line.split("output: ")[1]: previous for previous, line in zip(run.stdout.splitlines(),
                                                                           run.stdout.splitlines()[1:])
              if line.startswith("    output: ") and line.endswith("/scene.h5")}
    assert str(bvh) in inputs["results/pants/sequences/held_out_000/scene.h5"]
    assert str(bvh) not in inputs["results/pants/sequences/train_000/scene.h5"]
    bvh.unlink()
    missing = snakemake(tmp_path, "-n", "results/pants/", "--configfile", str(config))
    assert missing.returncode != 0
    assert f"{bvh}: BVH file of scene 'pants' does not exist" in missing.stdout + missing.stderr


def test_bare_snakemake_plans_the_default_scene_and_every_job_has_log_benchmark_and_resources(tmp_path):
    run = snakemake(tmp_path, "-n", "-p")
    assert run.returncode == 0, tail(run)
    jobs = planned_jobs(run)
    assert set(jobs) == STAGES | {"all"}
    scene = CONFIG["default_scene"]
    assert all(job["wildcards"].startswith(f"scene={scene}") for name, job in jobs.items() if name != "all")
    assert f"wildcards: scene={scene}, seq=held_out_000" in run.stdout     # the held-out sequence is planned
    for name in STAGES:
        job, seq = jobs[name], jobs[name]["wildcards"].split("seq=")[-1] + "/" if name in PER_SEQUENCE else ""
        assert job["log"] == f"results/{scene}/logs/{seq}{name}.log"
        assert job["benchmark"] == f"results/{scene}/benchmarks/{seq}{name}.tsv"
        assert "mem_mb=" in job["resources"] and "gpu=1" not in job["resources"]   # the cpu profile: no GPU
        assert name in SETTINGS_RULES or job["shell"].endswith(f" 2>&1 | tee {job['log']}")
    assert jobs["train"]["threads"] == jobs["evaluate"]["threads"] == jobs["dataset"]["threads"] == "2"   # --cores 2

    other = snakemake(tmp_path, "-n", "--config", "default_scene=patch", "device=cuda:0")
    assert other.returncode == 0, tail(other)
    jobs = planned_jobs(other)
    assert set(jobs) == STAGES | {"all"}
    assert all(job["wildcards"] in ("scene=patch", "scene=patch, seq=train_000")
               for name, job in jobs.items() if name != "all")
    assert {name for name, job in jobs.items() if "gpu=1" in job.get("resources", "")} == ON_DEVICE


def test_no_config_value_reaches_a_shell_command(tmp_path):
    """Stages get file paths, --settings, --threads and --quiet only: a config value written into a shell string
    would be run by the shell (here: a quote and a command substitution in the architecture)."""
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["patch"]["network"] = {"arch": "D62' $(touch pwned) 'D8"}
    evil = tmp_path / "evil.yaml"
    evil.write_text(yaml.safe_dump(config))
    # The operator comparison sizes its grid from the scene's architecture when the workflow loads, so the planted
    # one is refused there, before any job; the shipped config's commands are then checked word by word.
    run = snakemake(tmp_path, "--configfile", str(evil), "-n", "-p", "results/patch/")
    assert run.returncode == 2 and "token 1 'D62'' of" in run.stderr, tail(run)
    assert not (tmp_path / "pwned").exists()
    run = snakemake(tmp_path, "-n", "-p", "results/patch/")
    assert run.returncode == 0, tail(run)
    shells = {name: job["shell"] for name, job in planned_jobs(run).items() if job.get("shell", "None") != "None"}
    assert set(shells) == STAGES - SETTINGS_RULES
    words = {"-m", "low", "high", "2>&1", "|", "tee", "--settings", "--scene", "--renders", "--videos", "--export",
             "--html", "--train-log", "--threads", "2", "--quiet", "--sequence", "--tradeoff-report",
             "--study-report", "--convs-report",
             "train_000"}     # the one sequence name of a grid scene
    for name, command in shells.items():
        python, *rest = shlex.split(command)
        assert Path(python).resolve() == Path(sys.executable).resolve()    # Snakemake's own interpreter
        module = "scene" if name == "sequence" else name.removesuffix("_low").removesuffix("_high")
        stage = f"pipeline.{module}"
        unexpected = [word for word in rest if word not in words and word != stage
                      and not word.startswith("results/patch/")]
        assert not unexpected, f"{name}: {unexpected} in {command}"
