"""`results/<scene>/tradeoff/` end to end on tiny pants: a cheaper low-res budget re-simulated and fed to the
scene's trained network, to a smaller one and to one trained on that budget's own inputs; the high-res solver at
a cheaper budget and with the other harmonic schedule; one table row per way to the high-res cloth, the plot and
the report; the table's arithmetic and the high-res rows' errors checked against the artifacts they were made
from. Then the plans: the CI patch's (the scene's own budget reusing the scene's runs and dataset) and a sharded
scene's (batch jobs per shard at every budget and high-res run)."""
import json
import shlex

import h5py
import numpy as np
import pytest
import yaml
from workflow_runs import REPO, planned_counts, planned_jobs, snakemake, tail, tiny_pants

from experiments.tradeoff.artifact import HIGH_RES, LEARNED, LOOP, read_tradeoff
from pipeline.artifacts.dataset import load_dataset

# Tiny pants simulate 2 substeps x 10 iterations, harmonic projection every substep (the defaults' schedule).
GRID = {"substeps": [1], "widths": [0.125], "epochs": 1, "matched": [1], "matched_widths": [],
        "high_res_budgets": [[1, 5]], "harmonic_every": ["iteration", "substep"]}


def tiny_grid(tmp_path, grid=GRID, **kwargs):
    """tiny_pants with its tradeoff grid (the whole block: the garments' paper-sized grid would fill the rest)."""
    path = tiny_pants(tmp_path, **kwargs)
    config = yaml.safe_load(path.read_text())
    config["profiles"]["cpu"]["scenes"]["pants"]["tradeoff"] = grid
    path.write_text(yaml.safe_dump(config))
    return path


def why(run):
    """What a failed run said, with the first traceback of a job run inside Snakemake (a `run:` block's)."""
    start = run.stderr.find("Traceback")
    return tail(run) + ("" if start < 0 else "\n" + run.stderr[start:start + 3000])


# The tests that read the built grid: tests/conftest.py's `tiny_pants_build` builds it with the scene (shard 2), in one
# run.
built_grid = pytest.mark.tiny_pants_target("results/pants/tradeoff/", tradeoff=GRID)


@pytest.fixture(scope="module")
def tradeoff(tiny_pants_build):
    assert "results/pants/tradeoff/" in tiny_pants_build.targets
    assert tiny_pants_build.run.returncode == 0, why(tiny_pants_build.run)
    return tiny_pants_build.workdir / "results" / "pants"


@built_grid
def test_the_table_has_a_row_per_way_to_the_high_res_cloth_with_finite_positive_figures(tradeoff):
    out = tradeoff / "tradeoff"
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = read_tradeoff(out / "tradeoff.h5")
    c = table.columns
    assert (table.reference.substeps, table.reference.iterations, table.reference.harmonic_every) == (2, 10, "substep")
    assert c["method"].tolist() == [LEARNED] * 3 + [LOOP, HIGH_RES, HIGH_RES]
    assert c["network"].tolist() == ["RC9 x0.25", "RC9 x0.125", "RC9 x0.25", "none", "none", "none"]
    assert c["trained_substeps"].tolist() == [2, 2, 1, 0, 0, 0]       # the scene's budget, then the matched one
    assert list(zip(c["substeps"], c["iterations"], c["harmonic_every"])) == [
        (1, 10, "")] * 4 + [(1, 5, "substep"), (2, 10, "iteration")]
    assert c["params"][0] == c["params"][2] > c["params"][1] > 0 and not c["params"][3:].any()
    for name in ("l1_test", "l2_test", "l1_heldout", "l2_heldout", "ms_total", "ms_sim_high", "speedup"):
        assert np.all(np.isfinite(c[name]) & (c[name] > 0)), name
    low_res = c["method"] != HIGH_RES
    assert np.all((c["ms_sim_low"] > 0) == low_res) and np.all((c["ms_subdiv"] > 0) == low_res)
    assert np.all((c["ms_net"] > 0) == (c["method"] == LEARNED))
    assert np.all((c["ms_sim_high_run"] > 0) == ~low_res)
    np.testing.assert_allclose(c["ms_total"], c["ms_sim_low"] + c["ms_subdiv"] + c["ms_net"] + c["ms_sim_high_run"])
    np.testing.assert_allclose(c["speedup"], c["ms_sim_high"] / c["ms_total"])
    assert table.threads >= 1 and table.device.startswith("cpu")
    report = (out / "report.md").read_text()
    assert "](pareto.png)" in report and "[report.md](../report.md)" in report and "## Findings" in report
    assert "Matched training at 1 substeps: RC9 x0.25 trained on 1-substep inputs" in report
    rows = report.split("|---")[-1].splitlines()[1:]
    assert len(rows) == 6 and all(row.startswith("| ") for row in rows)


@built_grid
def test_the_high_res_times_are_one_sequence_alone_in_a_sharded_scene(tradeoff):
    """The scene is sharded (its runs are batches of 2): each high-res row's ms is the median solve_ms of the first
    sequence re-simulated alone with that budget and schedule, not a batch's over 2; the reference is one value,
    the free run the stage timed itself (no timing run of its own), the CPU fused columns NaN."""
    table = read_tradeoff(tradeoff / "tradeoff" / "tradeoff.h5")
    for row, folder in ((4, "h1x5_substep"), (5, "h2x10_iteration")):
        with h5py.File(tradeoff / "tradeoff" / folder / "timing" / "sim_high.h5") as f:
            assert f.attrs["batch"] == 1 and f["positions"].shape[0] == len(f["solve_ms"])
            ms = float(np.median(f["solve_ms"][1:]))        # frame 0: the initial state, not solved
        assert table.columns["ms_sim_high_run"][row] == ms
    assert len(set(table.columns["ms_sim_high"])) == 1 and not (tradeoff / "tradeoff" / "h2x10_substep").exists()
    for name in ("ms_net_fused", "fused_error", "ms_total_fused", "speedup_fused"):
        assert np.all(np.isnan(table.columns[name])), name


@built_grid
def test_the_learned_rows_are_the_evaluations_and_runs_of_their_budget(tradeoff):
    """Errors are eval.h5's of the budget's own dataset, each network's and Loop subdivision's; the budget's
    low-res run is a re-simulation with its substeps (not the scene's run); the smaller network was trained at
    its width on the scene's dataset, the matched one on the budget's."""
    table = read_tradeoff(tradeoff / "tradeoff" / "tradeoff.h5")
    for row, net in enumerate(("scene", "w0.125", "matched")):
        with h5py.File(tradeoff / "tradeoff/s1" / net / "eval.h5") as f:
            assert table.columns["l1_test"][row] == f["errors/network/test/l1"][()]
            assert table.columns["l2_heldout"][row] == f["errors/network/held_out/l2"][()]
            assert table.columns["l1_heldout"][3] == f["errors/predictor/held_out/l1"][()]
    with h5py.File(tradeoff / "sequences/train_000/sim_low.h5") as scene_run, \
            h5py.File(tradeoff / "tradeoff/s1/sequences/train_000/sim_low.h5") as cheap_run:
        assert not np.allclose(scene_run["positions"][-1], cheap_run["positions"][-1])
        assert json.loads(cheap_run.attrs["config"])["solver"]["substeps"] == 1
    for folder, width, dataset in (("w0.125", 0.125, "results/pants/dataset.h5"),
                                   ("s1/matched", 0.25, "results/pants/tradeoff/s1/dataset.h5")):
        with h5py.File(tradeoff / "tradeoff" / folder / "train.h5") as f:
            config = json.loads(f.attrs["config"])
            assert (config["width"], config["dataset"]) == (width, dataset)


def dataset_frame(positions, torso):
    """R^T (x - t) per frame: world positions (F, V, 3) in the torso frames (F, 4, 4)."""
    return np.einsum("fji,fvj->fvi", torso[:, :3, :3], positions - torso[:, None, :3, 3])


@built_grid
def test_the_high_res_rows_score_their_runs_against_the_scenes_high_res_run_on_the_datasets_frames(tradeoff):
    """Each high-res run's errors, recomputed from the scene's dataset (its truth S x_low + target, in the torso
    frame) and the run's own positions turned into that frame with each sequence's scene.h5; the run was made with
    its budget and schedule, held to the scene's low-res run."""
    table = read_tradeoff(tradeoff / "tradeoff" / "tradeoff.h5")
    data = load_dataset(tradeoff / "dataset.h5")
    truth = data.predictor.astype(np.float64) + data.targets
    with h5py.File(tradeoff / "dataset.h5") as f:
        sequence, frame = f["sequence"][()], f["sequence_frame"][()]
        names = [n.decode() for n in f["sequences/names"][()]]
        splits = {"test": f["split/test"][()], "heldout": f["split/held_out"][()]}
    for row, folder, (substeps, iterations, schedule) in ((4, "h1x5_substep", (1, 5, "substep")),
                                                          (5, "h2x10_iteration", (2, 10, "iteration"))):
        ours = np.empty_like(truth)
        for k, name in enumerate(names):
            with h5py.File(tradeoff / "tradeoff" / folder / "sequences" / name / "sim_high.h5") as run, \
                    h5py.File(tradeoff / "sequences" / name / "scene.h5") as scene:
                config = json.loads(run.attrs["config"])
                assert (config["solver"]["substeps"], config["solver"]["iterations"],
                        config["high_res"]["harmonic_every"]) == (substeps, iterations, schedule)
                rows = np.flatnonzero(sequence == k)
                torso = scene["torso_transforms"][()][frame[rows]]
                ours[rows] = dataset_frame(run["positions"][()][frame[rows]], torso)
        for split, ids in splits.items():
            difference = ours[ids] - truth[ids]
            assert table.columns[f"l1_{split}"][row] == pytest.approx(np.abs(difference).mean(), rel=1e-3)
            assert table.columns[f"l2_{split}"][row] == pytest.approx(
                np.sqrt(np.square(difference).sum(axis=2).mean()), rel=1e-3)


def run_plan(tmp_path, target, *args):
    run = snakemake(tmp_path, "-n", "-p", target, *args)
    assert run.returncode == 0, tail(run)
    return run


def test_matched_widths_train_the_scenes_recipe_at_each_width_on_the_matched_budgets_inputs(tmp_path):
    """`tradeoff.matched_widths` on the CI patch: at the matched budget 1 (not its own 4), a network of each width
    trained on the budget's dataset (settings: the budget's, with that width), evaluated there and fed to the
    stage as another --matched network."""
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("profiles: {cpu: {scenes: {patch: {tradeoff: {matched_widths: [0.125, 0.5]}}}}}\n")
    run = run_plan(tmp_path, "--configfile", str(REPO / "workflow_config.yaml"), str(overlay), "--",
                   "results/patch/tradeoff/")
    counts = planned_counts(run)
    assert (counts["tradeoff_matched_settings"], counts["tradeoff_train_matched_width"]) == (2, 2)
    assert counts["tradeoff_train_matched"] == 1 and counts["tradeoff_evaluate"] == 9
    stage = next(line for line in run.stdout.splitlines() if "-m experiments.tradeoff " in line)
    for width in ("0.125", "0.5"):
        folder = f"results/patch/tradeoff/s1/matched_w{width}"
        assert f" --matched 1 {folder}/eval.h5 {folder}/model.pt" in stage
        assert any("-m pipeline.train results/patch/tradeoff/s1/dataset.h5 " in line and f"{folder}/model.pt" in line
                   and f"--settings {folder}/settings.json" in line for line in run.stdout.splitlines())
    assert "s4/matched" not in run.stdout


def test_a_budget_of_fewer_iterations_has_its_own_folder_runs_and_networks(tmp_path):
    """A low-res budget [1, 10] on the CI patch (its own 4 x 30): folder s1x10/ with its settings, runs, dataset,
    the scene-trained networks fed it and, matched there, the scene's recipe and a narrower one trained on its
    inputs; the stage is given it as budget 1x10 beside the 1-substep budget at the scene's 30 iterations."""
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("profiles: {cpu: {scenes: {patch: {tradeoff: {substeps: [1, [1, 10]], matched: [[1, 10]], "
                       "matched_widths: [0.125]}}}}}\n")
    run = run_plan(tmp_path, "--configfile", str(REPO / "workflow_config.yaml"), str(overlay), "--",
                   "results/patch/tradeoff/")
    counts = planned_counts(run)
    assert (counts["tradeoff_settings"], counts["tradeoff_simulate_low"], counts["tradeoff_dataset"]) == (2, 2, 2)
    assert (counts["tradeoff_train_matched"], counts["tradeoff_train_matched_width"]) == (1, 1)
    folder = "results/patch/tradeoff/s1x10"
    stage = next(line for line in run.stdout.splitlines() if "-m experiments.tradeoff " in line)
    assert (f" --point 1x10 {folder}/sequences/train_000/sim_low.h5 --eval 1x10 {folder}/scene/eval.h5 "
            "results/patch/model.pt" in stage)
    assert f" --matched 1x10 {folder}/matched/eval.h5 {folder}/matched/model.pt" in stage
    assert f" --matched 1x10 {folder}/matched_w0.125/eval.h5 {folder}/matched_w0.125/model.pt" in stage
    assert " --point 1 results/patch/tradeoff/s1/sequences/train_000/sim_low.h5 " in stage
    assert "--matched 1 " not in stage and "s1/matched" not in run.stdout
    assert any("-m pipeline.simulate low " in line and f"{folder}/simulation.json" in line
               and f"{folder}/sequences/train_000/sim_low.h5" in line for line in run.stdout.splitlines())
    assert any("-m pipeline.train " in line and f"{folder}/dataset.h5" in line and f"{folder}/matched/model.pt" in line
               for line in run.stdout.splitlines())


def test_the_patch_plan_has_a_job_per_budget_sequence_and_network_with_logs_and_only_paths_in_shells(tmp_path):
    """The cpu profile's grid on the CI patch (budgets 1, 2 and its own 4 x its one sequence; the scene's network,
    one of width 0.125 and one trained on 1-substep inputs; high-res 1 x 10, 2 x 15 and its own 4 x 30 with the
    every-iteration projection): the jobs it plans, each with log, benchmark and resources, the device's GPU asked
    for by the jobs that run on it, and shells of paths, flags and the grid's numbers and schedule names only. The
    scene's own budget re-simulates nothing and evaluates on the scene's dataset."""
    run = run_plan(tmp_path, "results/patch/tradeoff/", "--config", "device=cuda:0")
    counts = planned_counts(run)
    rules = ("tradeoff_settings", "tradeoff_simulate_low", "tradeoff_sequence_links", "tradeoff_dataset",
             "tradeoff_evaluate", "tradeoff_network_settings", "tradeoff_train", "tradeoff_train_matched",
             "tradeoff_high_settings", "tradeoff_simulate_high", "tradeoff")
    assert {name: counts.get(name) for name in rules} == {
        "tradeoff_settings": 3, "tradeoff_simulate_low": 2, "tradeoff_sequence_links": 2, "tradeoff_dataset": 2,
        "tradeoff_evaluate": 7, "tradeoff_network_settings": 1, "tradeoff_train": 1, "tradeoff_train_matched": 1,
        "tradeoff_high_settings": 3, "tradeoff_simulate_high": 3, "tradeoff": 1}
    jobs = {name: job for name, job in planned_jobs(run).items() if name.startswith("tradeoff")}
    for name, job in jobs.items():
        assert job["log"].startswith("results/patch/tradeoff/") and "mem_mb=" in job["resources"], name
        on_device = {"tradeoff_simulate_low", "tradeoff_simulate_high", "tradeoff_evaluate", "tradeoff_train",
                     "tradeoff_train_matched", "tradeoff"}
        assert ("gpu=1" in job["resources"]) == (name in on_device), name
        if name not in ("tradeoff_settings", "tradeoff_network_settings", "tradeoff_high_settings",
                        "tradeoff_sequence_links"):
            assert "benchmark" in job, name
            words = shlex.split(job["shell"])[1:]
            assert [w for w in words if not (w.startswith(("results/patch/", "-")) or w.isdigit() or w in
                                             {"low", "high", "iteration", "substep", "2>&1", "|", "tee"}
                                             or w.startswith(("pipeline.", "experiments.")))] == [], job["shell"]
    stage = next(line for line in run.stdout.splitlines() if "-m experiments.tradeoff " in line)
    assert (" --solve-timing results/patch/sequences/train_000/scene.h5 results/patch/sequences/train_000/sim_low.h5 "
            in stage) and "--settled" not in stage
    assert (" --point 4 results/patch/sequences/train_000/sim_low.h5 --eval 4 results/patch/tradeoff/s4/scene/eval.h5"
            in stage)
    assert " --matched 1 results/patch/tradeoff/s1/matched/eval.h5 " in stage and "--matched 4" not in stage
    assert " --high-res 4 30 iteration results/patch/tradeoff/h4x30_iteration/sequences/train_000/sim_high.h5" in stage
    assert "h4x30_substep" not in stage                 # the scene's own high-res run: the reference
    assert "s4/dataset.h5" not in run.stdout
    assert any("-m pipeline.evaluate results/patch/dataset.h5 " in line and "/tradeoff/s4/scene/" in line
               for line in run.stdout.splitlines())


def test_a_sharded_scene_simulates_by_shard_and_times_one_sequence_alone(tmp_path):
    """With `shard: 2`, each cheaper budget's low-res runs and each high-res run are a batch job per shard (as the
    scene's); a high-res run's ms comes from a run of the first sequence alone, and the budgets' low-res ms and the
    free reference's are the stage's own timing of the first sequence (--solve-timing): no timing run of theirs."""
    grid = {**GRID, "substeps": [1, 2], "high_res_budgets": [[1, 5], [2, 10]]}
    run = run_plan(tmp_path, "results/pants/tradeoff/", "--configfile", str(tiny_grid(tmp_path, grid, shard=2)))
    counts = planned_counts(run)
    assert (counts["tradeoff_simulate_low_batch_pants_000"], counts["tradeoff_simulate_low_batch_pants_001"]) == (
        1, 1)                                                  # budget 1 re-simulated
    assert (counts["tradeoff_simulate_high_batch_pants_000"], counts["tradeoff_simulate_high_batch_pants_001"],
            counts["tradeoff_timing_high"]) == (2, 2, 2)       # 1 x 5 and the every-iteration 2 x 10
    assert counts["tradeoff_high_settings"] == 2
    assert not {"tradeoff_simulate_low", "tradeoff_simulate_high", "tradeoff_timing_low"} & set(counts)
    stage = next(line for line in run.stdout.splitlines() if "-m experiments.tradeoff " in line)
    assert (" --solve-timing results/pants/sequences/train_000/scene.h5 results/pants/sequences/train_000/sim_low.h5 "
            in stage)
    assert " --point 1 results/pants/tradeoff/s1/sequences/train_000/sim_low.h5 --eval 1 " in stage
    assert " --point 2 results/pants/sequences/train_000/sim_low.h5 --eval 2 " in stage
    assert "--sim-high-timing" not in stage and "h2x10_substep" not in stage
    assert " --high-res-timing 1 5 substep results/pants/tradeoff/h1x5_substep/timing/sim_high.h5 " in stage
    assert " --high-res-timing 2 10 iteration results/pants/tradeoff/h2x10_iteration/timing/sim_high.h5 " in stage
    timing = [line for line in run.stdout.splitlines()
              if "-m pipeline.simulate high " in line and "/timing/sim_high.h5" in line]
    assert len(timing) == 2 and all(" results/pants/sequences/train_000/sim_low.h5 " in line for line in timing)
