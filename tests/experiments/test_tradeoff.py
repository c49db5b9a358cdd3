"""The tradeoff stage's pieces against independent references: the Pareto front against a brute-force pairwise
check, the per-sequence ms of a batched run, the Loop subdivision timing, a budget's rows against hand-computed
figures of the evaluations they come from, a high-res run's error against the reference computed frame by frame
with the losses the training uses, the findings' arithmetic, tradeoff.h5's round trip, and the stage's
refusals."""
import h5py
import numpy as np
import pytest
import scipy.sparse as sp
import torch
from scipy.spatial.transform import Rotation

from experiments.tradeoff.artifact import (COLUMNS, HIGH_RES, LEARNED, LOOP, Reference, Tradeoff, read_tradeoff,
                                          write_tradeoff)
from experiments.tradeoff.report import findings, labels, pareto_front
from experiments.tradeoff.solve_timing import LowResMs
from experiments.tradeoff.stage import (NO_LOW_RES, NOT_TIMED, Budget, Network, NetworkMs, budget_rows,
                                        high_res_errors, main, make_row, parse_grid, parse_high_res, per_sequence_ms,
                                        table_of, time_subdivision)
from model.losses import l1_loss, l2_loss
from pipeline.artifacts.dataset import SEQUENCE, SEQUENCE_FRAME, SEQUENCE_NAMES, SPLIT_HELD_OUT, SPLIT_TEST
from pipeline.artifacts.dataset import read_frame_origins
from pipeline.artifacts.evaluation import Evaluation, read_network_timing, write_evaluation
from pipeline.artifacts.scene import TORSO_TRANSFORMS
from pipeline.artifacts.simulation import SimulationRun, write_simulation
from pipeline.core.errors import PipelineError

REFERENCE = Reference(4, 30, "substep")


def sweeps(ms):
    """A low-res solve of `ms` timed with one frame kernel, the sweeps."""
    return LowResMs(ms, "sweeps")


def brute_force_front(ms, error):
    front = []
    for i in range(len(ms)):
        beaten = any(ms[j] <= ms[i] and error[j] <= error[i] and (ms[j] < ms[i] or error[j] < error[i])
                     for j in range(len(ms)) if j != i)
        front.append(not beaten)
    return np.array(front)


@pytest.mark.parametrize("seed", range(5))
def test_pareto_front_is_the_points_no_other_point_beats(seed):
    rng = np.random.default_rng(seed)
    ms, error = rng.integers(1, 6, 12).astype(float), rng.integers(1, 6, 12).astype(float)   # ties on purpose
    np.testing.assert_array_equal(pareto_front(ms, error), brute_force_front(ms, error))


def test_pareto_front_keeps_equal_points_and_drops_a_dominated_one():
    np.testing.assert_array_equal(pareto_front([1, 1, 2, 3], [5, 5, 1, 2]), [True, True, True, False])


def run_with(solve_ms, batch, positions=None):
    positions = np.zeros((len(solve_ms), 3, 3), dtype=np.float32) if positions is None else positions
    return SimulationRun(positions, np.array([[0, 1, 2]]), np.zeros((positions.shape[1], 3)), np.array([0]),
                         np.asarray(solve_ms, dtype=float), 1, batch_worlds=batch)


def test_per_sequence_ms_is_the_median_over_solved_frames_of_batch_ms_over_its_sequences(tmp_path):
    paths = [str(tmp_path / "a.h5"), str(tmp_path / "b.h5")]
    write_simulation(paths[0], "low", {}, run_with([0.0, 4.0, 8.0, 100.0], 2), "cpu", "x")
    write_simulation(paths[1], "low", {}, run_with([0.0, 6.0, 1.0], 1), "cpu", "x")
    ms, batch = per_sequence_ms(paths)
    assert batch == 2
    assert ms == np.median([2.0, 4.0, 50.0, 6.0, 1.0])   # frame 0 (the initial state) left out


def test_a_run_without_a_solved_frame_is_refused(tmp_path):
    path = str(tmp_path / "a.h5")
    write_simulation(path, "low", {}, run_with([0.0], 1), "cpu", "x")
    with pytest.raises(PipelineError, match="solve_ms"):
        per_sequence_ms([path])


def test_time_subdivision_times_each_requested_frame():
    S = sp.random(30, 10, density=0.3, random_state=0, format="csr")
    times = time_subdivision(S, np.random.default_rng(0).normal(size=(4, 10, 3)), torch.device("cpu"), 7)
    assert times.shape == (7,) and np.all(np.isfinite(times) & (times > 0))


def write_eval(path, network, predictor, inference_ms, params, conv="RC9", width=0.25, device="cpu, 2 threads",
               spec=None):
    """An eval.h5 as the evaluate stage writes it: errors per split (split -> (l1, l2)), timing, model spec."""
    errors = {who: {split: {"l1": l1, "l2": l2} for split, (l1, l2) in splits.items()}
              for who, splits in (("network", network), ("predictor", predictor))}
    write_evaluation(path, {"model_spec": {"conv": conv, "width": width} if spec is None else spec},
                     Evaluation(errors, {}, np.zeros((1, 3, 3)), np.asarray(inference_ms, dtype=float),
                                np.arange(len(inference_ms)), device, 3, params, 100))
    return str(path)


def test_a_budgets_rows_are_its_networks_then_the_matched_ones_then_loop_alone_with_summed_times(tmp_path):
    predictor = {"test": (3.0, 4.0), "held_out": (5.0, 6.0)}
    scene = write_eval(tmp_path / "s.h5", {"test": (1.0, 1.5), "held_out": (2.0, 2.5)}, predictor, [2.0, 9.0, 4.0],
                       1000)
    small = write_eval(tmp_path / "w.h5", {"test": (1.2, 1.7), "held_out": (2.2, 2.7)}, predictor, [1.0], 250,
                       width=0.125)
    matched = write_eval(tmp_path / "m.h5", {"test": (0.9, 1.1), "held_out": (1.8, 1.9)}, predictor, [3.0, 5.0],
                         1000)
    matched_small = write_eval(tmp_path / "mw.h5", {"test": (1.1, 1.3), "held_out": (2.0, 2.1)}, predictor, [1.0],
                               250, width=0.125)
    budget = Budget(1, 30, ["low.h5"], [Network(scene, "s.pt"), Network(small, "w.pt")],
                    [Network(matched, "m.pt"), Network(matched_small, "mw.pt")])
    rows = budget_rows(budget, Reference(4, 30, "substep"), sim_low=sweeps(10.0), ms_subdiv=0.5, ms_sim_high=200.0,
                       ms_net={"s.pt": NetworkMs(4.0), "w.pt": NetworkMs(1.0), "m.pt": NetworkMs(4.0),
                               "mw.pt": NetworkMs(0.5)})
    assert [(r["method"], r["network"], r["trained_substeps"], r["trained_iterations"], r["params"])
            for r in rows] == [
        (LEARNED, "RC9 x0.25", 4, 30, 1000), (LEARNED, "RC9 x0.125", 4, 30, 250), (LEARNED, "RC9 x0.25", 1, 30, 1000),
        (LEARNED, "RC9 x0.125", 1, 30, 250), (LOOP, "none", 0, 0, 0)]
    assert [r["ms_net"] for r in rows] == [4.0, 1.0, 4.0, 0.5, 0.0]    # each model's own timing, not its evaluation's
    assert [r["ms_total"] for r in rows] == [14.5, 11.5, 14.5, 11.0, 10.5]        # 10 + 0.5 + network
    assert [r["speedup"] for r in rows] == [200 / 14.5, 200 / 11.5, 200 / 14.5, 200 / 11.0, 200 / 10.5]
    assert [(r["l1_test"], r["l2_heldout"]) for r in rows] == [(1.0, 2.5), (1.2, 2.7), (0.9, 1.9), (1.1, 2.1),
                                                                (3.0, 6.0)]
    assert all(r["substeps"] == 1 and r["iterations"] == 30 and r["harmonic_every"] == "" for r in rows)


def test_an_evaluation_without_its_network_spec_or_timed_frames_is_refused(tmp_path):
    path = write_eval(tmp_path / "e.h5", {"test": (1, 1)}, {"test": (1, 1)}, [1.0], 10, spec={"conv": "RC9"})
    with pytest.raises(PipelineError, match="'width' missing or malformed: not an eval.h5 of pipeline.evaluate"):
        read_network_timing(path)
    path = write_eval(tmp_path / "f.h5", {"test": (1, 1)}, {"test": (1, 1)}, [1.0], 10)
    with h5py.File(path, "r+") as f:
        del f["inference_ms"]
        f["inference_ms"] = np.zeros(0)
    with pytest.raises(PipelineError, match="at least one timed frame"):
        read_network_timing(path)


def test_a_row_without_a_held_out_split_has_nan_there_and_its_speedup_is_the_reference_over_its_total():
    row = make_row(HIGH_RES, "none", 2, 15, (0, 0), 0, {"test": {"l1": 0.1, "l2": 0.2}}, NO_LOW_RES, 0.0, NOT_TIMED,
                   20.0,
                   "substep",
                   ms_sim_high_run=5.0)
    assert np.isnan(row["l1_heldout"]) and np.isnan(row["l2_heldout"])
    assert (row["ms_total"], row["speedup"], row["harmonic_every"]) == (5.0, 4.0, "substep")
    assert make_row(LEARNED, "n", 1, 10, (4, 10), 9, {"test": {"l1": 1, "l2": 1}}, sweeps(1.0), 2.0,
                    NetworkMs(4.0),
                    70.0)["speedup"] == 10.0
    assert list(row) == list(COLUMNS)


def write_dataset_origins(path, names, sequence, sequence_frame, test, held_out, torso=None):
    """The part of a dataset.h5 read_frame_origins reads, under the dataset stage's names."""
    with h5py.File(path, "w") as f:
        f[SEQUENCE_NAMES] = np.array(names, dtype="S")
        f[SEQUENCE], f[SEQUENCE_FRAME] = np.asarray(sequence, np.int32), np.asarray(sequence_frame, np.int64)
        f[SPLIT_TEST], f[SPLIT_HELD_OUT] = np.asarray(test, np.int64), np.asarray(held_out, np.int64)
        f.attrs["frame"] = "world" if torso is None else "torso"
        if torso is not None:
            f[TORSO_TRANSFORMS] = torso
    return str(path)


def random_torso(rng, n):
    transforms = np.tile(np.eye(4), (n, 1, 1))
    transforms[:, :3, :3] = Rotation.random(n, random_state=rng.integers(1 << 30)).as_matrix()
    transforms[:, :3, 3] = rng.normal(size=(n, 3))
    return transforms


@pytest.fixture
def two_sequences(tmp_path):
    """Reference and cheaper high-res runs of two sequences (6 and 5 frames of 4 vertices), and a dataset whose
    frames are frames 2..5 of the first (its settle frames 0, 1 dropped) and 0..4 of the second (held out)."""
    rng = np.random.default_rng(3)
    paths = {}
    for name, n in (("a", 6), ("b", 5)):
        for kind in ("ref", "run"):
            positions = rng.normal(size=(n, 4, 3)).astype(np.float32)
            paths[kind, name] = str(tmp_path / f"{kind}_{name}.h5")
            write_simulation(paths[kind, name], "high", {}, run_with(np.ones(n), 1, positions), "cpu", "x")
    sequence, frames = [0, 0, 0, 0, 1, 1, 1, 1, 1], [2, 3, 4, 5, 0, 1, 2, 3, 4]
    layout = dict(names=["a", "b"], sequence=sequence, sequence_frame=frames, test=[1, 3], held_out=[4, 5, 6, 7, 8])
    return paths, layout, rng


def brute_force_errors(paths, layout, torso):
    """Per split: stack each frame's positions in the dataset's frame (R^T (x - t), vertex by vertex) and take the
    training losses over the stack."""
    out = {}
    for split in ("test", "held_out"):
        run, ref = [], []
        for i in layout[split]:
            name = layout["names"][layout["sequence"][i]]
            frame = layout["sequence_frame"][i]
            for kind, stack in (("run", run), ("ref", ref)):
                x = h5py.File(paths[kind, name])["positions"][frame].astype(np.float64)
                if torso is not None:
                    x = np.array([torso[i, :3, :3].T @ (v - torso[i, :3, 3]) for v in x])
                stack.append(x)
        run, ref = torch.as_tensor(np.stack(run)), torch.as_tensor(np.stack(ref))
        out[split] = {"l1": l1_loss(run, ref).item(), "l2": l2_loss(run, ref).item()}
    return out


@pytest.mark.parametrize("in_torso_frame", [False, True])
def test_high_res_errors_are_the_training_losses_over_each_splits_frames_in_the_datasets_frame(
        tmp_path, two_sequences, in_torso_frame):
    paths, layout, rng = two_sequences
    torso = random_torso(rng, len(layout["sequence"])) if in_torso_frame else None
    origins = read_frame_origins(write_dataset_origins(tmp_path / "d.h5", **layout, torso=torso))
    errors = high_res_errors(origins, [paths["ref", "a"], paths["ref", "b"]], [paths["run", "a"], paths["run", "b"]])
    expected = brute_force_errors(paths, layout, torso)
    for split in ("test", "held_out"):
        assert errors[split]["l1"] == pytest.approx(expected[split]["l1"], rel=1e-9)
        assert errors[split]["l2"] == pytest.approx(expected[split]["l2"], rel=1e-9)
    if in_torso_frame:          # L2 is a distance, rotation-invariant; L1 sums coordinates, so the frame matters
        world = brute_force_errors(paths, layout, None)
        assert errors["held_out"]["l2"] == pytest.approx(world["held_out"]["l2"], rel=1e-9)
        assert errors["held_out"]["l1"] != pytest.approx(world["held_out"]["l1"], rel=1e-6)


def test_a_run_scored_against_itself_has_no_error_and_mismatched_runs_are_refused(tmp_path, two_sequences):
    paths, layout, _ = two_sequences
    origins = read_frame_origins(write_dataset_origins(tmp_path / "d.h5", **layout))
    refs = [paths["ref", "a"], paths["ref", "b"]]
    assert high_res_errors(origins, refs, refs) == {"test": {"l1": 0.0, "l2": 0.0}, "held_out": {"l1": 0.0, "l2": 0.0}}
    with pytest.raises(PipelineError, match="2 reference runs for a dataset of 2 sequences"):
        high_res_errors(origins, refs, refs[:1])
    with pytest.raises(PipelineError, match="positions"):
        high_res_errors(origins, refs, refs[::-1])          # 6 and 5 frames swapped


def test_a_dataset_without_test_frames_is_refused(tmp_path):
    path = write_dataset_origins(tmp_path / "d.h5", ["a"], [0, 0], [0, 1], [], [])
    with pytest.raises(PipelineError, match="empty"):
        read_frame_origins(path)


def table(rows, reference=REFERENCE):
    return table_of(rows, "cpu, 2 threads", 2, reference)


def learned(n, trained, l1, total, network="RC9 x0.25", iterations=30):
    """A learned row at n substeps x `iterations`, its network trained on `trained` substeps (at the scene's 30
    iterations if that is the scene's 4 substeps, else at the row's own iterations: a matched network)."""
    inputs = (trained, 30 if trained == REFERENCE.substeps else iterations)
    return make_row(LEARNED, network, n, iterations, inputs, 100, {"test": {"l1": l1, "l2": l1}}, sweeps(total), 0.0,
                    NOT_TIMED, 100.0)


def test_findings_say_what_the_input_shift_costs_and_how_much_matched_training_removes():
    rows = [learned(1, 4, 3e-3, 10.0), learned(1, 1, 2e-3, 10.0), learned(4, 4, 1e-3, 40.0),
            make_row(HIGH_RES, "none", 1, 10, (0, 0), 0, {"test": {"l1": 5e-4, "l2": 6e-4}}, NO_LOW_RES, 0.0, NOT_TIMED,
                     100.0,
                     "substep", ms_sim_high_run=25.0)]
    lines = findings(table(rows))
    assert ("Input shift: RC9 x0.25 trained on 4-substep inputs has test L1 3.000 fed 1-substep runs against 1.000 "
            "at its own budget (+200%).") in lines
    assert ("Matched training at 1 substeps: RC9 x0.25 trained on 1-substep inputs has test L1 2.000 against 3.000 "
            "trained on 4-substep inputs and 1.000 at 4 substeps: it removes 50% of the input shift.") in lines
    assert any(line.startswith("High-res at 1 x 10, harmonic projection every substep: test L1 0.500") and
               "25 ms a frame (4.00x)" in line for line in lines)
    assert lines[-1] == ("For 60 Hz (16.7 ms a frame) on this device: 1 sub, RC9 x0.25 (matched), test L1 2.000 in "
                         "10 ms.")
    assert ("No learned path has a test L1 at least 5% below Loop subdivision alone's at its budget."
            in lines)   # no Loop rows


def test_a_budget_of_fewer_iterations_is_its_own_budget_in_the_findings_and_labels():
    """1 x 10 (the scene: 4 x 30): the scene-trained network fed it, the matched one trained on it, its Loop row;
    the 1 x 30 budget beside it is another budget (its Loop row is not 1 x 10's)."""
    def loop(n, iterations, l1, ms):
        return make_row(LOOP, "none", n, iterations, (0, 0), 0, {"test": {"l1": l1, "l2": l1}}, sweeps(ms), 0.0,
                        NOT_TIMED, 100.0)
    rows = [learned(1, 4, 3e-3, 6.0, iterations=10), learned(1, 1, 2e-3, 5.0, iterations=10),
            loop(1, 10, 3.1e-3, 2.0), learned(1, 4, 2.5e-3, 12.0), loop(1, 30, 1.9e-3, 8.0),
            learned(4, 4, 1e-3, 40.0)]
    written = table(rows)
    assert labels(written)[:3] == ["1 x 10, RC9 x0.25", "1 x 10, RC9 x0.25 (matched)", "1 x 10, Loop only"]
    assert labels(written)[3:5] == ["1 sub, RC9 x0.25", "1 sub, Loop only"]
    lines = findings(written)
    assert ("Input shift: RC9 x0.25 trained on 4-substep inputs has test L1 3.000 fed 1 x 10 runs against 1.000 "
            "at its own budget (+200%).") in lines
    assert ("Matched training at 1 x 10: RC9 x0.25 trained on 1 x 10 inputs has test L1 2.000 against 3.000 "
            "trained on 4-substep inputs and 1.000 at 4 substeps: it removes 50% of the input shift.") in lines
    assert ("Fastest learned path at least 5% below Loop subdivision alone's test L1 at its budget: 1 x 10, RC9 x0.25 "
            "(matched), test L1 2.000 against Loop's 3.100 (1.55x lower), 5 ms a frame: **20.0x** the reference "
            "high-res run.") in lines


def test_findings_name_the_fastest_learned_path_clearly_below_loop_subdivision_fused_where_faster():
    """Budget 1: Loop alone 3.0; the scene-trained network (2.9, 5 ms) is 3 % below it, no gain a user sees (the
    input shift's networks land there), so the matched one (2.0, 12 ms, fused 6 ms) is named though slower; budget
    4's network (1.0) is slower still (40 ms)."""
    def loop(n, l1, ms):
        return make_row(LOOP, "none", n, 30, (0, 0), 0, {"test": {"l1": l1, "l2": l1}}, sweeps(ms), 0.0, NOT_TIMED,
                        100.0)
    rows = [learned(1, 4, 2.9e-3, 5.0), make_row(LEARNED, "RC9 x0.125", 1, 30, (1, 30), 50,
                                                 {"test": {"l1": 2e-3, "l2": 2e-3}},
                                                 sweeps(4.0), 0.0, NetworkMs(8.0, 2.0, 1e-2), 100.0),
            loop(1, 3e-3, 4.0), learned(4, 4, 1e-3, 40.0), loop(4, 1.5e-3, 39.0)]
    lines = findings(table(rows))
    assert ("Fastest learned path at least 5% below Loop subdivision alone's test L1 at its budget: 1 sub, RC9 x0.125 "
            "(matched) with the fused bf16 network, test L1 2.000 against Loop's 3.000 (1.50x lower), 6 ms a frame: "
            "**16.7x** the reference high-res run.") in lines


def test_tradeoff_h5_round_trips_and_refuses_ragged_columns_nan_and_unknown_methods(tmp_path):
    rows = [learned(1, 4, 1e-3, 10.0),
            make_row(LOOP, "none", 1, 30, (0, 0), 0,
                     {"test": {"l1": 2e-3, "l2": 3e-3}, "held_out": {"l1": 4e-3, "l2": 5e-3}}, sweeps(10.0), 0.5,
                     NOT_TIMED,
                     100.0)]
    written = table(rows)
    write_tradeoff(tmp_path / "t.h5", {}, written)
    back = read_tradeoff(tmp_path / "t.h5")
    assert (back.device, back.threads, back.reference) == ("cpu, 2 threads", 2, REFERENCE)
    for name in COLUMNS:
        np.testing.assert_array_equal(back.columns[name], written.columns[name])
    assert np.isnan(back.columns["l1_heldout"][0]) and back.columns["method"].tolist() == [LEARNED, LOOP]

    def broken(**columns):
        write_tradeoff(tmp_path / "bad.h5", {}, Tradeoff({**written.columns, **columns}, "cpu", 1, REFERENCE))
        return tmp_path / "bad.h5"

    with pytest.raises(PipelineError, match="one value per row"):
        read_tradeoff(broken(params=np.array([1, 2, 3])))
    with pytest.raises(PipelineError, match="'speedup' contains NaN"):
        read_tradeoff(broken(speedup=np.array([1.0, np.nan])))
    with pytest.raises(PipelineError, match="'method' holds 'magic'"):
        read_tradeoff(broken(method=np.array(["magic", LOOP])))


@pytest.mark.parametrize("points, evals, matched, message", [
    ([["0", "l.h5"]], [["0", "e.h5", "e.pt"]], [], "positive integers"),
    ([["2x"]], [["2", "e.h5", "e.pt"]], [], "BUDGET must be N"),
    ([["2x0", "l.h5"]], [["2", "e.h5", "e.pt"]], [], "BUDGET must be N"),
    ([["2"]], [["2", "e.h5", "e.pt"]], [], "at least one SIM_LOW"),
    ([["2", "l.h5"], ["2", "m.h5"]], [["2", "e.h5", "e.pt"]], [], "once"),
    ([["2", "l.h5"], ["2x30", "m.h5"]], [["2", "e.h5", "e.pt"]], [], "once"),    # 2 is 2 x the scene's 30
    ([["2", "l.h5"]], [["3", "e.h5", "e.pt"]], [], "--eval 3 e.h5: no --point of that budget"),
    ([["2", "l.h5"]], [["2x10", "e.h5", "e.pt"]], [], "--eval 2x10 e.h5: no --point of that budget"),
    ([["2", "l.h5"]], [["2", "e.h5", "e.pt"]], [["3", "m.h5", "m.pt"]], "--matched 3 m.h5: no --point"),
    ([["2", "l.h5"]], [["2", "e.h5", "e.pt"]], [["2", "m.h5", "m.pt"], ["2", "m.h5", "n.pt"]], "given twice"),
    ([["2", "l.h5"]], [["2", "e.h5", "e.pt"]], [["2", "e.h5", "e.pt"]], "given twice"),
    ([["2", "l.h5"], ["1", "m.h5"]], [["2", "e.h5", "e.pt"]], [], "--point 1: no --eval")])
def test_bad_grids_are_refused(points, evals, matched, message):
    with pytest.raises(PipelineError, match=message):
        parse_grid(points, evals, matched, 30)


def test_the_grid_is_in_budget_order_with_each_budgets_evaluations_in_the_order_given():
    """A bare N is N substeps at the scene's iterations (30 here); NxI another budget, ordered by substeps then
    iterations."""
    grid = parse_grid([["4", "a", "b"], ["1", "c"], ["1x10", "d"]],
                      [["4", "e4", "p"], ["1", "e1", "p"], ["4", "f4", "q"], ["1x10", "g1", "p"]],
                      [["1", "m1", "r"], ["1x10", "n1", "s"]], 30)
    assert grid == [Budget(1, 10, ["d"], [Network("g1", "p")], [Network("n1", "s")]),
                    Budget(1, 30, ["c"], [Network("e1", "p")], [Network("m1", "r")]),
                    Budget(4, 30, ["a", "b"], [Network("e4", "p"), Network("f4", "q")], [])]


@pytest.mark.parametrize("group, message", [
    (["1", "10", "substep"], "SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH"),
    (["1", "0", "substep", "h.h5"], "ITERATIONS must be a positive integer"),
    (["1", "10", "sometimes", "h.h5"], "SCHEDULE must be one of iteration, substep"),
    (["4", "30", "substep", "h.h5"], "the scene's own high-res run, the ground truth")])
def test_bad_high_res_runs_are_refused(group, message):
    with pytest.raises(PipelineError, match=message):
        parse_high_res([group], REFERENCE)


def test_high_res_runs_keep_their_order_and_each_is_given_once():
    runs = parse_high_res([["4", "30", "iteration", "a", "b"], ["1", "10", "substep", "c"]], REFERENCE)
    assert [(r.substeps, r.iterations, r.harmonic_every, r.runs, r.timed) for r in runs] == [
        (4, 30, "iteration", ["a", "b"], ["a", "b"]), (1, 10, "substep", ["c"], ["c"])]
    with pytest.raises(PipelineError, match="given twice"):
        parse_high_res([["1", "10", "substep", "a"], ["1", "10", "substep", "b"]], REFERENCE)


def test_a_high_res_run_is_timed_by_its_timing_runs_when_given():
    runs = parse_high_res([["4", "30", "iteration", "a", "b"], ["1", "10", "substep", "c"]], REFERENCE,
                          [["1", "10", "substep", "t"]])
    assert [(r.runs, r.timed) for r in runs] == [(["a", "b"], ["a", "b"]), (["c"], ["t"])]


@pytest.mark.parametrize("timing, message", [
    ([["2", "10", "substep", "t"]], "no --high-res run of that budget"),
    ([["1", "10", "substep", "t"], ["1", "10", "substep", "u"]], "given twice"),
    ([["1", "10", "substep"]], "SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH")])
def test_bad_high_res_timing_runs_are_refused(timing, message):
    with pytest.raises(PipelineError, match=message):
        parse_high_res([["1", "10", "substep", "c"]], REFERENCE, timing)


@pytest.mark.parametrize("missing", ["--dataset", "--operators"])
def test_without_the_dataset_or_the_operators_the_networks_cannot_be_timed_a_usage_error(tmp_path, capsys, missing):
    given = {"--dataset": "d.h5", "--operators": "o.h5"}
    del given[missing]
    with pytest.raises(SystemExit) as exit_:
        main(["subdiv.h5", str(tmp_path / "t.h5"), str(tmp_path / "p.png"), str(tmp_path / "r.md"),
              "--sim-high", "h.h5", "--point", "1", "l.h5", "--eval", "1", "e.h5", "e.pt",
              "--solve-timing", "s.h5", "l.h5", *[word for pair in given.items() for word in pair]])
    assert exit_.value.code == 2 and f"required: {missing}" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_without_the_settings_the_solvers_cannot_be_timed_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["subdiv.h5", str(tmp_path / "t.h5"), str(tmp_path / "p.png"), str(tmp_path / "r.md"),
              "--sim-high", "h.h5", "--point", "1", "l.h5", "--eval", "1", "e.h5", "e.pt",
              "--solve-timing", "s.h5", "l.h5", "--dataset", "d.h5", "--operators", "o.h5"])
    assert exit_.value.code == 2 and "--settings is required" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
