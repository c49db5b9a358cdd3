"""`results/multi/` end to end on tiny pants, skirt and tshirt (workflow_runs.py's tiny pants, one training
sequence each, a small network): one network trained on the three garments' own datasets and operators, its view
per garment evaluated by the evaluate stage, the table and report against each scene's own network; the plan of
the default config (jobs, logs, resources, shells of paths only; not part of `results/<scene>/`), a rerun that
touches no scene stage, and configs the target refuses in one line."""
import copy
import shlex

import h5py
import numpy as np
import pytest
import torch
import yaml
from workflow_runs import build, planned_counts, planned_jobs, snakemake, tail, tiny_pants

from experiments.multi.table import read_multi_table
from pipeline.artifacts.evaluation import read_errors, read_parameter_count
from pipeline.artifacts.operators import load_hierarchy

GARMENTS = ["pants", "skirt", "tshirt"]
TINY = {"network": {"arch": "D8 D16 D D16", "width": 1.0}, "operators": {"levels": 3},
        "evaluation": {"render_frames": 0, "video_frames": 0, "export_frames": 1, "timing_frames": 2}}
MULTI_RULES = {"multi_train", "multi_evaluate", "multi_report"}


def tiny_garments(workdir, **changes):
    """tiny_pants with one training sequence and a small network, copied to skirt and tshirt; `changes` (scene ->
    overlay) on top."""
    path = tiny_pants(workdir, sequences=1)
    config = yaml.safe_load(path.read_text())
    scenes = config["profiles"]["cpu"]["scenes"]
    scenes["pants"].update(copy.deepcopy(TINY))
    for garment in GARMENTS[1:]:
        scenes[garment] = copy.deepcopy(scenes["pants"])
    for scene, overlay in changes.items():
        scenes[scene].update(overlay)
    config["multi"] = {"scenes": GARMENTS}
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("multi")
    config = tiny_garments(workdir)
    run = build(workdir, "results/multi/", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    return workdir, config


def test_the_table_sets_the_shared_network_beside_each_garments_own_and_loop_subdivision(built):
    results = built[0] / "results"
    out = results / "multi"
    for name in ("model.pt", "train.h5", "multi.h5", "report.md"):
        assert (out / name).is_file(), name
    assert (out / "training_curve.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = read_multi_table(out / "multi.h5")
    assert table.garments == GARMENTS and table.splits == ["train", "test", "held_out"]
    assert len(set(table.vertices.tolist())) == 3                 # three meshes of their own
    for k, garment in enumerate(GARMENTS):
        shared, own = read_errors(out / garment / "eval.h5"), read_errors(results / garment / "eval.h5")
        assert table.parameters == read_parameter_count(results / garment / "eval.h5")     # the same size
        for split in table.splits:
            for term in ("l1", "l2"):
                assert table.errors["shared"][split][term][k] == shared["network"][split][term]
                assert table.errors["own"][split][term][k] == own["network"][split][term]
                assert table.errors["predictor"][split][term][k] == shared["predictor"][split][term]
                assert np.isfinite(shared["network"][split][term]) and shared["predictor"][split][term] > 0
        assert np.all(table.inference_ms["shared"] > 0)
        assert (out / garment / "report.md").read_text().count("Loop subdivision alone (predictor)") == 1
    report = (out / "report.md").read_text()
    assert all(f"| {g} | shared network (every garment) |" in report for g in GARMENTS)
    assert "](training_curve.png)" in report and "](../skirt/report.md)" in report


def test_one_network_trained_on_each_scenes_own_operators_and_datasets(built):
    results = built[0] / "results"
    state = torch.load(results / "multi/model.pt", weights_only=True)
    assert list(state["garments"]) == GARMENTS
    views = {g: torch.load(results / "multi" / g / "model.pt", weights_only=True)["state_dict"] for g in GARMENTS}
    own = torch.load(results / "pants/model.pt", weights_only=True)["state_dict"]
    for garment in GARMENTS:
        mesh = load_hierarchy(results / garment / "operators.h5", "RC9", 4)
        assert state["garments"][garment]["operators"]["fingerprint"] == mesh.fingerprint()
        with h5py.File(results / garment / "dataset.h5") as f:
            assert state["training"]["datasets"][garment] == f"results/{garment}/dataset.h5"
            assert torch.equal(views[garment]["features.faces"], torch.as_tensor(f["faces"][()].astype(np.int64)))
        for key, value in state["state_dict"].items():
            assert torch.equal(views[garment][f"net.{key}"], value)          # every garment: the one network
    assert not torch.equal(views["pants"]["net.convs.0.weight"], own["net.convs.0.weight"])
    assert not list((results / "multi").glob("*/dataset.h5")) and not list((results / "multi").glob("**/*.ckpt"))


def test_a_rerun_of_the_shared_training_runs_no_scene_stage(built):
    workdir, config = built
    run = snakemake(workdir, "-n", "results/multi/", "--configfile", str(config), "--forcerun", "multi_train")
    assert run.returncode == 0, tail(run)
    assert set(planned_counts(run)) - {"total"} == MULTI_RULES | {"results/multi/"}
    assert planned_counts(run)["multi_evaluate"] == 3


def test_the_default_plan_has_its_jobs_logs_and_resources_and_only_paths_in_shells(tmp_path):
    run = snakemake(tmp_path, "-n", "-p", "results/multi/", "--config", "device=cuda:0")
    assert run.returncode == 0, tail(run)
    counts = planned_counts(run)
    assert (counts["multi_train"], counts["multi_evaluate"], counts["multi_report"], counts["train"]) == (1, 3, 1, 3)
    jobs = {name: job for name, job in planned_jobs(run).items() if name in MULTI_RULES}
    for name, job in jobs.items():
        assert job["log"].startswith("results/multi/") and "mem_mb=" in job["resources"] and "benchmark" in job
        assert ("gpu=1" in job["resources"]) == (name != "multi_report"), name
        words = shlex.split(job["shell"])[1:]
        assert [w for w in words if not (w.startswith(("results/", "-", "pipeline.", "experiments.")) or w in
                                         {*GARMENTS, "train", "2", "2>&1", "|", "tee"})] == [], job["shell"]
    plan = snakemake(tmp_path, "-n", "results/pants/")
    assert plan.returncode == 0 and not set(planned_counts(plan)) & MULTI_RULES


def test_garments_that_cannot_share_a_network_are_refused_before_any_job(tmp_path):
    config = tiny_garments(tmp_path, skirt={"network": {"arch": "D8 D16 D D16", "width": 0.5}})
    run = snakemake(tmp_path, "-n", "results/multi/", "--configfile", str(config))
    assert run.returncode != 0
    assert "results/multi/: scenes 'pants' and 'skirt' differ in network" in run.stdout + run.stderr
    unknown = yaml.safe_load(config.read_text())
    unknown["multi"]["scenes"] = ["pants", "gown"]
    config.write_text(yaml.safe_dump(unknown))
    run = snakemake(tmp_path, "-n", "results/pants/", "--configfile", str(config))
    assert run.returncode != 0 and "multi.scenes: 'gown' is not a scene" in run.stdout + run.stderr
