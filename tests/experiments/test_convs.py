"""experiments.convs: the table, the wins and their spread, the report and the refusals, from hand-made runs
(eval.h5 and train.h5 as the evaluate and train stages write them) whose answers are known; the workflow's run of
the stage: test_workflow_convs.py."""
import itertools
import re

import numpy as np
import pytest

from experiments.convs.artifact import COLUMNS, read_convs
from experiments.convs.report import family_test, lowest, margin, rows, verdict, wins
from experiments.convs.stage import RECIPE as RECIPE_FLAGS
from experiments.convs.stage import gather, main
from pipeline.artifacts.evaluation import Evaluation, write_evaluation
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5

KINDS = ("RC", "EC", "SP", "SPD")
PREDICTOR = {"train": (9.0, 12.0), "test": (8.0, 11.0), "held_out": (7.0, 10.0)}
RECIPE = {"dataset": "results/x/dataset.h5", "epochs": 2, "batch_size": 3, "lr": 1e-3, "lr_schedule": "constant",
          "loss_l1": 1.0, "loss_l2": 0.0, "loss_normal": 0.0, "pool": "max", "inputs": "position",
          "input_frame": "dataset", "output_frame": "dataset", "frame_tangent": "edge", "input_noise": 0.0,
          "sample_share": 1.0, "sample_block": 1, "train_on": ["train"], "train_frames": None, "cuda_graph": False,
          "tf32": False, "deterministic": True}


def write_run(folder, kind, length, seed, l1, arch="D8 D16", task_splits=("train", "test", "held_out"),
              predictor=PREDICTOR, recipe=RECIPE, trained_seed=None, ms=(2.0, 4.0, 3.0), params=1234):
    """A run's eval.h5 and train.h5: network L1 `l1` on every split (L2 = 2 L1), the predictor's errors."""
    folder.mkdir(parents=True, exist_ok=True)
    errors = {"network": {split: {"l1": l1, "l2": 2 * l1} for split in task_splits},
              "predictor": {split: dict(zip(("l1", "l2"), predictor[split])) for split in task_splits}}
    evaluation = folder / "eval.h5"
    write_evaluation(evaluation, {"model_spec": {"arch": arch, "conv": f"{kind}{length}", "width": 0.5}},
                     Evaluation(errors, {}, None, np.asarray(ms), np.arange(len(ms)), "cpu, 2 threads", 3, params,
                                100))
    train_log = folder / "train.h5"
    with atomic_h5(train_log, "train", {**recipe, "seed": seed if trained_seed is None else trained_seed,
                                        "conv": f"{kind}{length}"}) as f:
        f.attrs["wall_seconds"] = 12.5
    return str(evaluation), str(train_log)


def grid_runs(tmp_path, l1, seeds=(0,), lengths=(9,), task="upsampling", kinds=KINDS, **kwargs):
    """--run words for every operator x length x seed; l1(kind, length, seed) gives each run's error."""
    return [(task, str(seed), *write_run(tmp_path / task / f"{kind}{length}" / f"s{seed}", kind, length, seed,
                                          l1(kind, length, seed), **kwargs))
            for length in lengths for kind in kinds for seed in seeds]


def test_the_table_has_a_row_per_run_with_its_evaluation_and_training(tmp_path):
    l1 = lambda kind, length, seed: 0.001 * (KINDS.index(kind) + 1) + 1e-4 * seed + 1e-5 * length   # noqa: E731
    runs = grid_runs(tmp_path, l1, seeds=(0, 1), lengths=(9, 13))
    table, recipes = gather(runs)
    c = table.columns
    assert len(table) == 16 and set(c) == set(COLUMNS)
    assert set(RECIPE) == set(RECIPE_FLAGS) and recipes == {"upsampling": RECIPE}
    assert c["kind"].tolist() == [k for _ in (9, 13) for k in KINDS for _ in (0, 1)]
    assert c["length"].tolist() == [9] * 8 + [13] * 8 and c["seed"].tolist() == [0, 1] * 8
    np.testing.assert_allclose(c["l1_test"], [l1(k, n, s) for n in (9, 13) for k in KINDS for s in (0, 1)])
    np.testing.assert_allclose(c["l2_heldout"], 2 * c["l1_heldout"])
    assert np.all(c["loop_l1_heldout"] == 7.0) and np.all(c["loop_l2_train"] == 12.0)
    assert np.all(c["ms_inference"] == 3.0) and np.all(c["train_seconds"] == 12.5) and np.all(c["params"] == 1234)
    assert set(c["arch"]) == {"D8 D16"} and np.all(c["width"] == 0.5) and table.device == "cpu, 2 threads"


def brute_force_lowest(values):
    """kind -> seeds' values: the lowest mean, and whether every seed of it is below every seed of the others."""
    best = min(values, key=lambda kind: np.mean(values[kind]))
    others = np.concatenate([v for kind, v in values.items() if kind != best])
    return best, len(values[best]) > 1 and bool(np.max(values[best]) < np.min(others))


@pytest.mark.parametrize("seed", range(5))
def test_the_lowest_and_its_clearness_and_the_win_counts_match_a_brute_force(tmp_path, seed):
    rng = np.random.default_rng(seed)
    centres = {(kind, length): rng.uniform(1, 2) for kind in KINDS for length in (9, 13)}
    noise = rng.uniform(0, 0.3)
    draws = {key: rng.uniform(-noise, noise, 3) for key in centres}
    runs = grid_runs(tmp_path, lambda kind, length, s: 1e-3 * (centres[kind, length] + draws[kind, length][s]),
                     seeds=(0, 1, 2), lengths=(9, 13))
    table_rows = rows(gather(runs)[0])
    assert [row.length for row in table_rows] == [9, 13]
    counted = {kind: [0, 0] for kind in KINDS}
    for row in table_rows:
        for column in ("l1_train", "l1_test", "l1_heldout"):
            values = {kind: 1e-3 * (centres[kind, row.length] + draws[kind, row.length]) for kind in KINDS}
            assert lowest(row, column) == brute_force_lowest(values)
            best, clear = brute_force_lowest(values)
            counted[best][0] += 1
            counted[best][1] += clear
    count = wins(table_rows, "l1")
    assert count.cases == 6 and {kind: [count.lowest[kind], count.clear[kind]] for kind in KINDS} == counted


def test_a_win_by_less_than_the_seeds_spread_is_not_clear_and_one_seed_is_never_clear(tmp_path):
    spread = {"RC": [1.0, 1.5, 1.2], "EC": [1.4, 1.6, 1.7], "SP": [2.0, 2.1, 2.2], "SPD": [3.0, 3.0, 3.1]}
    row = rows(gather(grid_runs(tmp_path / "a", lambda k, n, s: spread[k][s], seeds=(0, 1, 2)))[0])[0]
    assert lowest(row, "l1_test") == ("RC", False)                 # RC's 1.5 above EC's 1.4
    apart = {**spread, "RC": [1.0, 1.1, 1.3]}
    row = rows(gather(grid_runs(tmp_path / "b", lambda k, n, s: apart[k][s], seeds=(0, 1, 2)))[0])[0]
    assert lowest(row, "l1_test") == ("RC", True)
    row = rows(gather(grid_runs(tmp_path / "c", lambda k, n, s: {"RC": 1, "EC": 5, "SP": 5, "SPD": 5}[k]))[0])[0]
    assert lowest(row, "l1_test") == ("RC", False)


def test_the_margin_is_the_best_spiral_over_the_best_of_ours(tmp_path):
    errors = {"RC": 2.0, "EC": 1.6, "SP": 2.4, "SPD": 2.0}
    row = rows(gather(grid_runs(tmp_path, lambda k, n, s: errors[k]))[0])[0]
    assert margin(row, "l1_test") == pytest.approx(2.0 / 1.6)
    assert margin(rows(gather(grid_runs(tmp_path / "one", lambda k, n, s: 1.0, kinds=("RC", "EC")))[0])[0],
                  "l1_test") is None                                   # no spiral operator to compare with


def exact_signed_rank_p(differences):
    """Two-sided exact p of Wilcoxon's signed-rank statistic by enumerating every sign assignment of the ranks
    (no ties, no zeros): the reference `family_test` is checked against."""
    ranks = np.argsort(np.argsort(np.abs(differences))) + 1
    observed = ranks[differences > 0].sum()
    totals = np.array([sum(r for r, sign in zip(ranks, signs) if sign)
                       for signs in itertools.product((0, 1), repeat=len(ranks))])
    return min(1.0, 2 * min(np.mean(totals <= observed), np.mean(totals >= observed)))


def test_a_family_lower_in_every_training_has_the_exact_signed_rank_p(tmp_path):
    # RC 2 % below SP/SPD and EC in each of 2 rows x 3 seeds: all 6 log ratios positive, p = 2 / 2^6.
    base = {(n, s): 1.0 + 0.1 * s + 0.01 * n for n in (9, 13) for s in range(3)}
    runs = grid_runs(tmp_path, lambda k, n, s: 1e-3 * base[n, s] * (0.98 if k == "RC" else 1.0),
                     seeds=(0, 1, 2), lengths=(9, 13))
    table_rows = rows(gather(runs)[0])
    test = family_test(table_rows)
    assert test.split == "heldout" and len(test.ratios) == 6
    np.testing.assert_allclose(test.ratios, 1 / 0.98)
    assert test.p_value == pytest.approx(2 / 2 ** 6)
    assert "RC/EC lower, beyond the trainings' noise" in verdict(table_rows)[0]


@pytest.mark.parametrize("seed", range(3))
def test_the_family_test_matches_an_enumeration_of_the_sign_assignments(tmp_path, seed):
    rng = np.random.default_rng(seed)
    factor = {(k, n, s): rng.uniform(0.95, 1.05) for k in KINDS for n in (9, 13) for s in range(4)}
    runs = grid_runs(tmp_path, lambda k, n, s: 1e-3 * factor[k, n, s], seeds=(0, 1, 2, 3), lengths=(9, 13),
                     task_splits=("train", "test"))
    test = family_test(rows(gather(runs)[0]))
    expected = [min(factor[k, n, s] for k in KINDS[2:]) / min(factor[k, n, s] for k in KINDS[:2])
                for n in (9, 13) for s in range(4)]
    assert test.split == "test"                           # no held-out split measured
    np.testing.assert_allclose(test.ratios, expected)
    assert test.p_value == pytest.approx(exact_signed_rank_p(np.log(expected)))


def test_operators_alike_are_no_family_win_and_a_single_family_has_no_test(tmp_path):
    runs = grid_runs(tmp_path / "alike", lambda k, n, s: 1e-3, seeds=(0, 1, 2))
    table_rows = rows(gather(runs)[0])
    assert family_test(table_rows).p_value == 1.0
    assert "neither family lower beyond the trainings' noise (p >= 0.05; with 3 trainings" in verdict(table_rows)[0]
    ours_only = grid_runs(tmp_path / "ours", lambda k, n, s: 1e-3, kinds=("RC", "EC"))
    assert family_test(rows(gather(ours_only)[0])) is None


def test_the_report_bolds_the_lowest_of_each_split_and_counts_the_wins(tmp_path):
    """RC lowest on every split by far (3 seeds a thousandth apart): bold in its three cells of the L1 and the L2
    table, and every win clear."""
    def l1(kind, length, seed):
        return 1e-3 * {"RC": 1.0, "EC": 2.0, "SP": 1.5, "SPD": 3.0}[kind] + 1e-6 * seed
    runs = grid_runs(tmp_path, l1, seeds=(0, 1, 2))
    out = tmp_path / "out"
    out.mkdir()
    words = [w for run in runs for w in ("--run", *run)]
    main([str(out / "convs.h5"), str(out / "convs.png"), str(out / "report.md"), str(out / "report.html"), *words])
    table = read_convs(out / "convs.h5")
    assert len(table) == 12 and (out / "convs.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "report.md").read_text()
    row = next(line for line in report.splitlines() if line.startswith("| D8 D16 x0.5 | 9 | 1,234 |"))
    cells = row.strip("|").split("|")[3:]                           # RC train, test, held-out, EC train, ...
    assert [i for i, cell in enumerate(cells) if "**" in cell] == [0, 1, 2]     # RC on every split: 1.0 lowest
    assert cells[0].strip() == "**1.001 ± 0.001**"                 # mean and sample sd of 1.000, 1.001, 1.002
    assert "RC/EC have the lowest L1 in 3 of 3 cases" in report and "RC/EC 3, SP/SPD 0" in report
    assert "| upsampling | RC | 3 of 3 | 3 | 3 of 3 | 3 |" in report
    assert f"Best SP/SPD over best RC/EC (above 1: RC/EC lower): {1.501 / 1.001:.3f} in the median case" in report
    html = (out / "report.html").read_text()
    assert len(re.findall(r"<td><strong>1\.001 ± 0\.001</strong></td>", html)) == 3     # L1: train, test, held-out
    assert len(re.findall(r"<td><strong>2\.002 ± 0\.002</strong></td>", html)) == 3     # L2 = 2 L1 here
    assert html.count("<td><strong>") == 6
    assert 'src="data:image/png;base64,' in html


def test_a_grid_without_a_held_out_split_has_nan_there(tmp_path):
    runs = grid_runs(tmp_path, lambda k, n, s: 1.0, task_splits=("train", "test"))
    table, _ = gather(runs)
    assert np.all(np.isnan(table.columns["l1_heldout"])) and np.all(np.isnan(table.columns["loop_l2_heldout"]))
    assert "l1_heldout" not in rows(table)[0].values and wins(rows(table)).cases == 2


def test_runs_that_do_not_fill_the_grid_are_refused(tmp_path):
    runs = grid_runs(tmp_path, lambda k, n, s: 1.0, seeds=(0, 1))
    with pytest.raises(PipelineError, match="'D8 D16' at L = 9 has no run of SPD with seed 1"):
        gather(runs[:-1])
    with pytest.raises(PipelineError, match="the same run as"):
        gather([*runs, runs[0]])


@pytest.mark.parametrize("change, message", [
    ({"recipe": {**RECIPE, "epochs": 3}}, "trained with different epochs: not the same recipe"),
    ({"predictor": {**PREDICTOR, "test": (8.5, 11.0)}}, "their predictor errors differ"),
    ({"trained_seed": 7}, "trained with seed 7 and conv SPD9, not the run's seed 0"),
    ({"arch": "U8 U3"}, "a network of 'U8 U3', not of task upsampling"),
    ({"recipe": {key: value for key, value in RECIPE.items() if key != "lr"}}, "its config has no 'lr'")])
def test_a_run_unlike_the_others_is_refused(tmp_path, change, message):
    runs = grid_runs(tmp_path, lambda k, n, s: 1.0)
    last = ("upsampling", "0", *write_run(tmp_path / "other", "SPD", 9, 0, 1.0, **change))
    with pytest.raises(PipelineError, match=re.escape(message)):
        gather([*runs[:-1], last])


def test_a_file_that_is_no_evaluation_is_one_error_naming_it(tmp_path):
    runs = grid_runs(tmp_path, lambda k, n, s: 1.0)
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not HDF5 at all" * 10)
    with pytest.raises(PipelineError, match=re.escape(str(garbage))):
        gather([*runs[:-1], ("upsampling", "0", str(garbage), runs[-1][3])])
    with pytest.raises(PipelineError, match=re.escape(str(garbage))):
        gather([*runs[:-1], ("upsampling", "0", runs[-1][2], str(garbage))])


def test_nothing_is_written_when_a_run_is_refused(tmp_path):
    runs = grid_runs(tmp_path, lambda k, n, s: 1.0)
    out = [str(tmp_path / name) for name in ("convs.h5", "convs.png", "report.md", "report.html")]
    with pytest.raises(PipelineError):
        main([*out, *[w for run in runs[:-1] for w in ("--run", *run)], "--run", "upsampling", "x", *runs[-1][2:]])
    assert not any((tmp_path / name).exists() for name in ("convs.h5", "convs.png", "report.md", "report.html"))


def part_of(tmp_path, name, runs):
    """The convs.h5 main writes from `runs`: a part of a grid run elsewhere."""
    out = [str(tmp_path / name / file) for file in ("convs.h5", "convs.png", "report.md", "report.html")]
    (tmp_path / name).mkdir()
    main([*out, *[word for run in runs for word in ("--run", *run)]])
    return out[0]


def by_run(table):
    """Each row's values keyed by (task, arch, length, kind, seed): tables compared whatever their rows' order."""
    c = table.columns
    return {(c["task"][k], c["arch"][k], c["length"][k], c["kind"][k], c["seed"][k]):
            [c[name][k].item() for name in COLUMNS] for k in range(len(table))}


def test_a_grid_run_in_parts_gives_the_table_of_all_its_runs_at_once(tmp_path):
    l1 = lambda kind, length, seed: 0.001 * (KINDS.index(kind) + 1) + 1e-4 * seed + 1e-5 * length   # noqa: E731
    runs = grid_runs(tmp_path, l1, seeds=(0, 1, 2), lengths=(9, 13))
    whole, recipes = gather(runs)
    seed_of = lambda run: run[1]                                   # noqa: E731
    first = part_of(tmp_path, "first", [run for run in runs if seed_of(run) == "0"])
    second = part_of(tmp_path, "second", [run for run in runs if seed_of(run) == "1"])
    joined, joined_recipes = gather([run for run in runs if seed_of(run) == "2"], [first, second])
    assert by_run(joined) == by_run(whole) and joined_recipes == recipes == {"upsampling": RECIPE}
    only_parts, _ = gather([], [part_of(tmp_path, "all", runs)])    # a part alone: its own table again
    assert by_run(only_parts) == by_run(whole)
    for mine, theirs in zip(rows(joined), rows(whole), strict=True):     # the report's rows: every seed's error
        for kind in KINDS:
            np.testing.assert_array_equal(np.sort(mine.values["l1_test"][kind]),
                                          np.sort(theirs.values["l1_test"][kind]))


def test_a_part_unlike_the_runs_or_overlapping_them_is_refused(tmp_path):
    runs = grid_runs(tmp_path / "a", lambda k, n, s: 1.0, seeds=(0, 1))
    seed1 = [run for run in runs if run[1] == "1"]
    part = part_of(tmp_path, "part", seed1)
    with pytest.raises(PipelineError, match="the same run as"):
        gather(runs, [part])                                       # seed 1 twice
    other = grid_runs(tmp_path / "b", lambda k, n, s: 1.0, seeds=(1,), recipe={**RECIPE, "epochs": 3})
    with pytest.raises(PipelineError, match="trained with different epochs"):
        gather([run for run in runs if run[1] == "0"], [part_of(tmp_path, "other", other)])
    fewer = part_of(tmp_path, "fewer", grid_runs(tmp_path / "c", lambda k, n, s: 1.0, seeds=(1,), kinds=KINDS[:3]))
    with pytest.raises(PipelineError, match="has no run of SPD with seed 1"):
        gather([run for run in runs if run[1] == "0"], [fewer])
    with pytest.raises(PipelineError, match="no runs: give --run or --part"):
        gather([])


def test_a_part_without_its_recipes_or_not_a_convs_file_is_one_error_naming_it(tmp_path):
    import h5py
    part = part_of(tmp_path, "part", grid_runs(tmp_path, lambda k, n, s: 1.0, seeds=(1,)))
    with h5py.File(part, "r+") as f:
        f.attrs["config"] = f.attrs["config"].replace('"recipes"', '"recipes_gone"')
    with pytest.raises(PipelineError, match=re.escape(f"{part}: its config has no recipe of each task's runs")):
        gather([], [part])
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(b"not HDF5 at all" * 10)
    with pytest.raises(PipelineError, match=re.escape(str(garbage))):
        gather([], [str(garbage)])
