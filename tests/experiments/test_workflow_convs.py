"""`results/<scene>/convs/` end to end on the CI patch (the cpu profile's tiny grid: RC, EC, SP and SPD at L = 9 on
the scene's architecture, one seed): one training and evaluation per operator on one operators.h5 holding every
table, and the table's contract checked against the artifacts it was made from. Then the plan of a garment scene's
grid: three architectures, two lengths, the pose decoder beside the upsampling."""
import json
import shlex

import h5py
import numpy as np
import pytest
import yaml
from workflow_runs import REPO, build, planned_counts, planned_jobs, snakemake, tail, tiny_pants

from experiments.convs.artifact import read_convs
from experiments.convs.stage import main
from model.networks import NetworkSpec, build_network

KINDS = ["RC", "EC", "SP", "SPD"]
RUNS = "results/patch/convs/upsampling/a0"


@pytest.fixture(scope="module")
def patch_convs(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("patch_convs")
    run = build(workdir, "results/patch/convs/")
    assert run.returncode == 0, tail(run)
    return workdir


def test_the_table_has_a_row_per_operator_made_from_its_own_run(patch_convs):
    table = read_convs(patch_convs / "results/patch/convs/convs.h5")
    c = table.columns
    assert c["kind"].tolist() == KINDS and c["task"].tolist() == ["upsampling"] * 4
    assert c["length"].tolist() == [9] * 4 and c["seed"].tolist() == [0] * 4
    settings = json.loads((patch_convs / "results/patch/convs/upsampling/settings.json").read_text())
    assert set(c["arch"]) == {settings["network"]["arch"]} and set(c["width"]) == {settings["network"]["width"]}
    built = build_network(NetworkSpec(settings["network"]["arch"], "RC9", "max", settings["network"]["width"], 3, 3))
    assert set(c["params"]) == {built.parameter_count()}
    for i, kind in enumerate(KINDS):
        folder = patch_convs / RUNS / f"{kind}9" / "s0"
        with h5py.File(folder / "eval.h5") as f:
            assert c["l1_train"][i] == f["errors/network/train/l1"][()]
            assert c["l2_test"][i] == f["errors/network/test/l2"][()]
            assert c["loop_l1_test"][i] == f["errors/predictor/test/l1"][()]
            assert c["ms_inference"][i] == np.median(f["inference_ms"][()])
        with h5py.File(folder / "train.h5") as f:
            config = json.loads(f.attrs["config"])
            assert (config["conv"], config["seed"], config["epochs"]) == (f"{kind}9", 0, settings["training"]["epochs"])
            assert config["operators"] == "results/patch/convs/operators.h5"
            assert c["train_seconds"][i] == f.attrs["wall_seconds"]
    for name in ("l1_train", "l2_train", "l1_test", "l2_test", "ms_inference"):
        assert np.all(np.isfinite(c[name]) & (c[name] > 0)), name
    assert np.all(np.isnan(c["l1_heldout"])) and np.all(np.isnan(c["loop_l2_heldout"]))    # a grid scene: none
    assert len(set(c["l1_train"])) == 4         # four different networks, not one trained four times


def test_the_workflows_table_joins_another_as_a_part_with_its_rows_unchanged(patch_convs, tmp_path):
    """A convs.h5 the workflow wrote is a part another machine's grid can join (convs.parts): its recipes are in
    it, and the stage given it alone writes the same rows again."""
    out = [str(tmp_path / name) for name in ("convs.h5", "convs.png", "report.md", "report.html")]
    main([*out, "--part", str(patch_convs / "results/patch/convs/convs.h5")])
    mine, theirs = read_convs(out[0]), read_convs(patch_convs / "results/patch/convs/convs.h5")
    assert mine.device == theirs.device and set(mine.columns) == set(theirs.columns)
    for name, values in theirs.columns.items():
        np.testing.assert_array_equal(mine.columns[name], values, err_msg=name)


def test_one_operators_file_holds_every_operators_table_and_they_differ(patch_convs):
    with h5py.File(patch_convs / "results/patch/convs/operators.h5") as f:
        tables = {kind: f[f"levels/0/conv/{kind}9"][()] for kind in KINDS}
    assert all(table.shape == tables["RC"].shape for table in tables.values())
    assert all(not np.array_equal(tables[a], tables[b]) for a in KINDS for b in KINDS if a < b)


def test_the_report_shows_the_papers_layout_with_the_lowest_in_bold_and_links_the_scenes(patch_convs):
    out = patch_convs / "results/patch/convs"
    table = read_convs(out / "convs.h5")
    report = (out / "report.md").read_text()
    assert (out / "convs.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "](convs.png)" in report and "[the scene's report](../report.md)" in report
    rows = [line for line in report.splitlines() if line.startswith("| D62 D124 D248 D D248 D_3 D248 x0.25 | 9 |")]
    assert len(rows) == 2                                                      # the L1 table, the L2 table
    for row, term in zip(rows, ("l1", "l2")):
        cells = [cell.strip() for cell in row.strip("|").split("|")[3:]]       # RC train, RC test, EC train, ...
        for s, split in enumerate(("train", "test")):
            column = [cells[2 * k + s] for k in range(4)]
            best = int(np.argmin(table.columns[f"{term}_{split}"]))
            assert [cell.startswith("**") for cell in column] == [k == best for k in range(4)], (term, split)
            assert column[best] == f"**{table.columns[f'{term}_{split}'][best] / 1e-3:.3f}**"
    assert "RC/EC have the lowest L1 in" in report and "of 2 cases" in report
    html = (out / "report.html").read_text()
    assert html.count("<td><strong>") == 4 and 'src="data:image/png;base64,' in html


def test_the_plan_of_a_garment_scene_has_every_architecture_length_and_the_pose_decoder(tmp_path):
    """Tiny pants' default grid (three architectures x RC, EC, SP, SPD at 9 and 13, one seed; the pose decoder at
    both lengths): its jobs, each with log, benchmark and resources, the GPU asked for by the ones on the device,
    and shells of paths, flags, the grid's operators and seeds and the resolved architectures only."""
    run = snakemake(tmp_path, "-n", "-p", "results/pants/convs/", "--configfile", str(tiny_pants(tmp_path)),
                    "--config", "device=cuda:0")
    assert run.returncode == 0, tail(run)
    counts = planned_counts(run)
    assert {name: counts.get(name) for name in ("convs_operators_settings", "convs_task_settings", "convs_operators",
                                                "convs_train", "convs_evaluate", "convs", "pose_dataset")} == {
        "convs_operators_settings": 1, "convs_task_settings": 2, "convs_operators": 1, "convs_train": 32,
        "convs_evaluate": 32, "convs": 1, "pose_dataset": 1}
    stage = next(line for line in run.stdout.splitlines() if "-m experiments.convs " in line)
    assert stage.count(" --run upsampling 0 ") == 24 and stage.count(" --run pose 0 ") == 8
    # The table reads the fp32 deployment path's time only: the evaluations skip the fused network's autotuning.
    evaluations = [line for line in run.stdout.splitlines() if "-m pipeline.evaluate " in line]
    assert len(evaluations) == 32 and all(" --no-fused-timing " in line for line in evaluations)
    trainings = [shlex.split(line) for line in run.stdout.splitlines() if "-m pipeline.train " in line]
    arches = {words[words.index("--arch") + 1] for words in trainings}
    assert arches == {"D62 D124 D248 D D248 D_3 D248", "D79 D158 D316 D_5 D316",
                      "D57 D57 D114 D114 D228 D228 D_2 D228", "U208 U U208 U U208 U U208 U104 U52 U3"}
    for name, job in planned_jobs(run).items():
        if not name.startswith("convs"):
            continue
        assert job["log"].startswith("results/pants/convs/") and "mem_mb=" in job["resources"], name
        assert ("gpu=1" in job["resources"]) == (name in ("convs_train", "convs_evaluate")), name
        if "shell" in job and job["shell"] != "None":
            assert "benchmark" in job, name
            words = shlex.split(job["shell"])[1:]
            assert [w for w in words if not (w.startswith(("results/pants/", "-", "pipeline.", "experiments."))
                                             or w.isdigit() or w in arches or w in {"upsampling", "pose", "2>&1",
                                                                                    "|", "tee"}
                                             or w.rstrip("0123456789") in KINDS)] == [], job["shell"]


def test_an_architecture_that_cannot_be_sized_stops_the_workflow_in_one_line(tmp_path):
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["defaults"]["convs"]["archs"] = ["scene", "D8 D16"]         # no x to solve for: the schema lets it by
    path = tmp_path / "fixed.yaml"
    path.write_text(yaml.safe_dump(config))
    run = snakemake(tmp_path, "-n", "results/patch/convs/", "--configfile", str(path))
    assert run.returncode != 0 and "Traceback" not in run.stdout + run.stderr
    assert "error: workflow config: convs.archs: 'D8 D16' has no channel count in x" in run.stdout + run.stderr
