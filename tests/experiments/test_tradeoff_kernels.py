"""Which frame kernels the trade-off times a low-res budget with (experiments.tradeoff.solve_timing), decided on
described GPUs without one: both where the sweeps and `auto` step the cloth differently (thread block clusters, a
cloth in a cluster's shared memory), the faster kept and reported beside the other's median in tradeoff.h5 and
report.md; else the scene's own kernel, once, as on the CPU."""
from pathlib import Path

import h5py
import numpy as np
import pytest
import warp as wp
import yaml

from experiments.tradeoff import solve_timing
from experiments.tradeoff.artifact import HIGH_RES, LEARNED, LOOP, Reference, read_tradeoff, write_tradeoff
from experiments.tradeoff.report import write_report
from experiments.tradeoff.solve_timing import LowResMs, TimedSequence, faster_kernel, kernels_to_time, low_res_ms
from experiments.tradeoff.stage import NO_LOW_RES, NOT_TIMED, NetworkMs, make_row, table_of
from pipeline.core.errors import PipelineError
from pipeline.core.config import resolve_scene
from sim.xpbd import SolverSettings
from sim.xpbd.block_frame import MAX_BLOCK_VERTICES, SHARED_VERTICES
from tests.sim.cloth_checks import FakeGpu

PANTS = 757          # the paper profile's low-res pants: in a cluster's shared memory


@pytest.mark.parametrize("frame_kernel", ["sweeps", "auto", "block"])
def test_both_kernels_are_timed_only_where_sweeps_and_auto_step_the_cloth_differently(frame_kernel):
    solver = SolverSettings(frame_kernel=frame_kernel)
    for gpu, vertices in ((FakeGpu(90), PANTS), (FakeGpu(100), SHARED_VERTICES)):
        assert kernels_to_time(solver, gpu, vertices, False) == ("sweeps", "block")
    scenes = "block" if frame_kernel == "block" else "sweeps"       # what the scene's setting steps: timed once
    assert kernels_to_time(solver, wp.get_device("cpu"), PANTS, False) == (scenes,)
    assert kernels_to_time(solver, FakeGpu(80), PANTS, False) == (scenes,)                   # no clusters
    assert kernels_to_time(solver, FakeGpu(90), SHARED_VERTICES + 1, False) == (scenes,)     # global memory
    assert kernels_to_time(solver, FakeGpu(90), MAX_BLOCK_VERTICES + 1, False) == ("sweeps",)   # fits no block
    assert kernels_to_time(solver, FakeGpu(90), PANTS, True) == ("sweeps",)     # the harmonic constraint


def test_the_faster_median_is_kept_beside_the_others():
    assert faster_kernel({"sweeps": 6.24, "block": 5.65}) == LowResMs(5.65, "block", 6.24)
    assert faster_kernel({"sweeps": 0.52, "block": 0.58}) == LowResMs(0.52, "sweeps", 0.58)
    once = faster_kernel({"block": 1.0})
    assert (once.ms, once.frame_kernel) == (1.0, "block") and np.isnan(once.other_ms)


@pytest.mark.parametrize("device, stepped, expected", [
    (FakeGpu(90), ["sweeps", "block"], LowResMs(5.0, "block", 6.0)),
    (FakeGpu(80), ["sweeps"], LowResMs(6.0, "sweeps")),
])
def test_a_budget_is_stepped_with_each_kernel_to_time_and_the_faster_kept(monkeypatch, device, stepped, expected):
    """low_res_ms of the patch scene's settings for a cloth of the pants' size on `device`, its solver stepped
    with the kernel its settings name (solve_ms: 6 ms a frame with the sweeps, 5 with the block)."""
    settings = resolve_scene(yaml.safe_load(open("workflow_config.yaml")), "patch", "cpu")
    kernels = []

    def solve_ms(simulation, level, group, device_name, settled):
        kernels.append(simulation["solver"]["frame_kernel"])
        return np.full(3, {"sweeps": 6.0, "block": 5.0}[kernels[-1]])

    monkeypatch.setattr(solve_timing, "solve_ms", solve_ms)
    monkeypatch.setattr(solve_timing, "read_rest_mesh", lambda path: (np.zeros((PANTS, 3)), None))
    monkeypatch.setattr(wp, "get_device", lambda name: device)
    timed = low_res_ms(settings, (8, 75), TimedSequence("scene.h5", "sim_low.h5"), "cuda:0")
    assert kernels == stepped
    assert (timed.ms, timed.frame_kernel) == (expected.ms, expected.frame_kernel)
    np.testing.assert_array_equal(timed.other_ms, expected.other_ms)


def rows(sim_low):
    errors = {"test": {"l1": 1e-3, "l2": 2e-3}}
    return [make_row(LEARNED, "RC9 x0.25", 8, 75, (8, 75), 100, errors, sim_low, 0.5, NetworkMs(2.0), 100.0),
            make_row(LOOP, "none", 8, 75, (0, 0), 0, errors, sim_low, 0.5, NOT_TIMED, 100.0),
            make_row(HIGH_RES, "none", 4, 30, (0, 0), 0, errors, NO_LOW_RES, 0.0, NOT_TIMED, 100.0, "substep",
                     ms_sim_high_run=50.0)]


def test_the_kernel_and_the_others_ms_are_recorded_and_reported_where_both_were_timed(tmp_path):
    table = table_of(rows(LowResMs(5.65, "block", 6.24)), "H200", 1, Reference(8, 75, "substep"))
    write_tradeoff(tmp_path / "t.h5", {}, table)
    back = read_tradeoff(tmp_path / "t.h5").columns
    assert back["sim_low_kernel"].tolist() == ["block", "block", ""]
    np.testing.assert_array_equal(back["ms_sim_low_other"], [6.24, 6.24, np.nan])
    assert back["ms_total"][0] == 5.65 + 0.5 + 2.0          # the faster kernel's ms is the row's
    write_report(tmp_path / "report.md", tmp_path / "pareto.png", tmp_path / "scene.md", table, (0, 0, 0))
    text = (tmp_path / "report.md").read_text()
    assert text.count("| 5.65 (block; sweeps 6.24) |") == 2 and "each was timed and the faster kept" in text

    once = table_of(rows(LowResMs(6.24, "sweeps")), "cpu", 1, Reference(8, 75, "substep"))
    write_report(tmp_path / "once.md", tmp_path / "pareto.png", tmp_path / "scene.md", once, (0, 0, 0))
    text = (tmp_path / "once.md").read_text()
    assert text.count("| 6.24 |") == 2 and "(sweeps" not in text and "faster kept" not in text


def test_a_table_from_before_the_frame_kernels_reads_as_the_sweeps(tmp_path):
    """tradeoff.h5 files written before sim_low_kernel and ms_sim_low_other (docs/data's pants grid among them)
    read with the values they stand for: the sweeps where a row has a low-res solve, the other kernel not timed,
    and they report. A file with one of the two columns only is refused."""
    table = table_of(rows(LowResMs(6.24, "sweeps")), "H100", 1, Reference(8, 75, "substep"))
    write_tradeoff(tmp_path / "t.h5", {}, table)
    with h5py.File(tmp_path / "t.h5", "a") as f:
        del f["sim_low_kernel"], f["ms_sim_low_other"]
    back = read_tradeoff(tmp_path / "t.h5")
    assert back.columns["sim_low_kernel"].tolist() == ["sweeps", "sweeps", ""]
    assert np.isnan(back.columns["ms_sim_low_other"]).all()
    np.testing.assert_array_equal(back.columns["ms_total"], table.columns["ms_total"])
    old = read_tradeoff(Path(__file__).parents[2] / "docs/data/tradeoff_pants_paper_h100.h5")
    assert len(old) == 21 and set(old.columns["sim_low_kernel"]) == {"sweeps", ""}
    write_report(tmp_path / "old.md", tmp_path / "old.png", tmp_path / "scene.md", old, (0, 0, 0))
    assert "(sweeps" not in (tmp_path / "old.md").read_text()
    write_tradeoff(tmp_path / "half.h5", {}, table)
    with h5py.File(tmp_path / "half.h5", "a") as f:
        del f["ms_sim_low_other"]
    with pytest.raises(PipelineError, match="ms_sim_low_other"):
        read_tradeoff(tmp_path / "half.h5")
