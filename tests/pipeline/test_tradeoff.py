"""The tradeoff stage's pieces against independent references: the Pareto front against a brute-force pairwise
check, the per-sequence ms of a batched run, the Loop subdivision timing, tradeoff.h5's
round trip, and the stage's refusals."""
import numpy as np
import pytest
import scipy.sparse as sp
import torch

from pipeline.artifacts.simulation import SimulationRun, write_simulation
from pipeline.artifacts.tradeoff import FLOAT_COLUMNS, INT_COLUMNS, Tradeoff, read_tradeoff, write_tradeoff
from pipeline.errors import PipelineError
from pipeline.tradeoff import pareto_front, parse_grid, per_sequence_ms, time_subdivision


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


def run_with(solve_ms, batch):
    positions = np.zeros((len(solve_ms), 3, 3), dtype=np.float32)
    return SimulationRun(positions, np.array([[0, 1, 2]]), np.zeros((3, 3)), np.array([0]), np.asarray(solve_ms),
                         1, batch_worlds=batch)


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


def test_tradeoff_h5_round_trips_and_refuses_ragged_columns(tmp_path):
    columns = {name: np.arange(1, 4) for name in INT_COLUMNS}
    columns.update({name: np.array([0.5, 1.0, 2.0]) for name in FLOAT_COLUMNS})
    columns["l1_heldout"] = np.array([0.5, np.nan, 2.0])    # a scene without a held-out motion has NaN there
    table = Tradeoff(["RC9 x0.25", "none", "RC9 x0.25"], columns, "cpu, 2 threads", 2, 4)
    write_tradeoff(tmp_path / "t.h5", {}, table)
    back = read_tradeoff(tmp_path / "t.h5")
    assert (back.network, back.device, back.threads, back.sim_high_batch) == (table.network, "cpu, 2 threads", 2, 4)
    for name, values in columns.items():
        np.testing.assert_array_equal(back.columns[name], values)
    write_tradeoff(tmp_path / "bad.h5", {}, Tradeoff(["a", "b"], columns, "cpu", 1, 1))
    with pytest.raises(PipelineError, match="one value per row"):
        read_tradeoff(tmp_path / "bad.h5")
    write_tradeoff(tmp_path / "nan.h5", {}, Tradeoff(table.network, {**columns, "speedup": columns["l1_heldout"]},
                                                      "cpu", 1, 1))
    with pytest.raises(PipelineError, match="'speedup' contains NaN"):
        read_tradeoff(tmp_path / "nan.h5")


@pytest.mark.parametrize("points, evals, message", [
    ([["0", "l.h5"]], [["0", "e.h5"]], "positive integer"),
    ([["2"]], [["2", "e.h5"]], "at least one SIM_LOW"),
    ([["2", "l.h5"], ["2", "m.h5"]], [["2", "e.h5"]], "once"),
    ([["2", "l.h5"]], [["3", "e.h5"]], "no --point 3"),
    ([["2", "l.h5"], ["1", "m.h5"]], [["2", "e.h5"]], "--point 1: no --eval")])
def test_bad_grids_are_refused(points, evals, message):
    with pytest.raises(PipelineError, match=message):
        parse_grid(points, evals)


def test_the_grid_is_in_budget_order_with_each_budgets_evaluations_in_the_order_given():
    grid = parse_grid([["4", "a", "b"], ["1", "c"]], [["4", "e4"], ["1", "e1"], ["4", "f4"]])
    assert grid == [(1, ["c"], ["e1"]), (4, ["a", "b"], ["e4", "f4"])]
