"""`results/<scene>/tradeoff/` end to end on tiny pants: each low-res budget re-simulated and fed to the scene's
trained network and to a smaller one, one table row per (budget, network or Loop alone), the plot and the
report; and the table's arithmetic checked against the artifacts it was made from."""
import shlex

import h5py
import numpy as np
import pytest
import yaml
from test_workflow import REPO, planned_counts, planned_jobs, snakemake, tail, tiny_pants

from pipeline.artifacts.tradeoff import read_tradeoff

BUDGETS = [1]         # below tiny pants' own low-res budget of 2 substeps: one budget keeps this test ~60 s


@pytest.fixture(scope="module")
def tradeoff(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("tradeoff")
    config_path = tiny_pants(workdir)
    config = yaml.safe_load(config_path.read_text())
    config["profiles"]["cpu"]["scenes"]["pants"]["tradeoff"] = {"substeps": BUDGETS, "widths": [0.125], "epochs": 1}
    config_path.write_text(yaml.safe_dump(config))
    run = snakemake(workdir, "results/pants/tradeoff/", "--configfile", str(config_path))
    assert run.returncode == 0, tail(run)
    return workdir / "results" / "pants"


def test_the_table_has_a_row_per_budget_and_network_with_finite_positive_figures(tradeoff):
    out = tradeoff / "tradeoff"
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = read_tradeoff(out / "tradeoff.h5")
    c = table.columns
    assert list(c["substeps"]) == [1, 1, 1] and list(c["iterations"]) == [10] * 3
    assert table.network == ["RC9 x0.25", "RC9 x0.125", "none"]
    assert c["params"][0] > c["params"][1] > 0 and c["params"][2] == 0
    for name in ("l1_test", "l2_test", "l1_heldout", "l2_heldout", "ms_sim_low", "ms_subdiv", "ms_total",
                 "ms_sim_high", "speedup"):
        assert np.all(np.isfinite(c[name]) & (c[name] > 0)), name
    assert np.all((c["ms_net"] > 0) == (c["params"] > 0))
    np.testing.assert_allclose(c["ms_total"], c["ms_sim_low"] + c["ms_subdiv"] + c["ms_net"])
    np.testing.assert_allclose(c["speedup"], c["ms_sim_high"] / c["ms_total"])
    assert table.threads >= 1 and table.device.startswith("cpu")
    report = (out / "report.md").read_text()
    assert "](pareto.png)" in report and report.count("| 1 x 10") + report.count("| **1 x 10") == 3


def test_the_rows_are_the_evaluations_and_runs_of_their_budget(tradeoff):
    """Errors are eval.h5's of the budget's own dataset, each network's and Loop subdivision's; the budget's
    low-res run is a re-simulation with its substeps (not the scene's run); the smaller network was trained at
    its width."""
    table = read_tradeoff(tradeoff / "tradeoff" / "tradeoff.h5")
    for row, net in enumerate(("scene", "w0.125")):
        with h5py.File(tradeoff / "tradeoff/s1" / net / "eval.h5") as f:
            assert table.columns["l1_test"][row] == f["errors/network/test/l1"][()]
            assert table.columns["l2_heldout"][row] == f["errors/network/held_out/l2"][()]
            assert table.columns["l1_heldout"][2] == f["errors/predictor/held_out/l1"][()]
    with h5py.File(tradeoff / "sequences/train_000/sim_low.h5") as scene_run, \
            h5py.File(tradeoff / "tradeoff/s1/sequences/train_000/sim_low.h5") as cheap_run:
        assert not np.allclose(scene_run["positions"][-1], cheap_run["positions"][-1])
        assert cheap_run.attrs["config"] and '"substeps": 1' in cheap_run.attrs["config"]
    with h5py.File(tradeoff / "tradeoff/w0.125/train.h5") as f:
        assert '"width": 0.125' in f.attrs["config"]


def test_the_patch_plan_has_a_job_per_budget_sequence_and_network_with_logs_and_only_paths_in_shells(tmp_path):
    """The cpu profile's grid on the CI patch (3 budgets x its one sequence, the scene's network and one of
    width 0.125): the jobs it plans, each with log, benchmark and resources, the device's GPU asked for by the
    jobs that run on it, and shells of paths and flags only (a width reaches one as a folder name)."""
    run = snakemake(tmp_path, "-n", "-p", "results/patch/tradeoff/", "--config", "device=cuda:0")
    assert run.returncode == 0, tail(run)
    counts = planned_counts(run)
    assert {name: counts.get(name) for name in ("tradeoff_settings", "tradeoff_simulate_low",
                                                 "tradeoff_sequence_links", "tradeoff_dataset", "tradeoff_evaluate",
                                                 "tradeoff_network_settings", "tradeoff_train", "tradeoff")} == {
        "tradeoff_settings": 3, "tradeoff_simulate_low": 3, "tradeoff_sequence_links": 3, "tradeoff_dataset": 3,
        "tradeoff_evaluate": 6, "tradeoff_network_settings": 1, "tradeoff_train": 1, "tradeoff": 1}
    jobs = {name: job for name, job in planned_jobs(run).items() if name.startswith("tradeoff")}
    for name, job in jobs.items():
        assert job["log"].startswith("results/patch/tradeoff/") and "mem_mb=" in job["resources"], name
        assert ("gpu=1" in job["resources"]) == (name in ("tradeoff_simulate_low", "tradeoff_evaluate",
                                                           "tradeoff_train", "tradeoff")), name
        if name not in ("tradeoff_settings", "tradeoff_network_settings", "tradeoff_sequence_links"):
            assert "benchmark" in job, name
            words = shlex.split(job["shell"])[1:]
            assert [w for w in words if not (w.startswith(("results/patch/", "-")) or w in
                                             {"low", "0", "1", "2", "4", "2>&1", "|", "tee"}
                                             or w.startswith("pipeline."))] == [], job["shell"]


def test_a_sharded_scene_resimulates_by_shard_and_times_one_sequence_alone(tmp_path):
    """With `shard: 2`, each budget's runs are a batch job per shard (as the scene's), and the budget's low-res
    ms comes from a run of the first sequence alone, the only run the stage is given for timing."""
    config = tiny_pants(tmp_path, shard=2)
    run = snakemake(tmp_path, "-n", "-p", "results/pants/tradeoff/", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    counts = planned_counts(run)
    assert (counts["tradeoff_simulate_low_batch_pants_000"], counts["tradeoff_simulate_low_batch_pants_001"],
            counts["tradeoff_timing_low"]) == (3, 3, 3)         # the cpu profile's 3 budgets
    assert "tradeoff_simulate_low" not in counts
    stage = next(line for line in run.stdout.splitlines() if "-m pipeline.tradeoff " in line)
    assert " --point 1 results/pants/tradeoff/s1/timing/sim_low.h5 --eval 1 " in stage
