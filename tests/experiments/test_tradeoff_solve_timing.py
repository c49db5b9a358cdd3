"""experiments.tradeoff.solve_timing and the `free` high-res level it times, on the CPU profile's patch scene
made through the stage CLIs: the free run starts where the held one does but is not held to the low-res run (its
harmonic residual is the drift the held run projects away), and each solver the stage times gives one finite ms
per stepped frame after the first."""
import subprocess
import sys

import h5py
import numpy as np
import pytest
import yaml

from experiments.tradeoff.solve_timing import TimedSequence, free_high_res_ms, low_res_ms, solve_ms
from pipeline.core.config import read_settings, resolve_scene, simulation_settings, write_settings


@pytest.fixture(scope="module")
def patch(tmp_path_factory):
    d = tmp_path_factory.mktemp("patch")
    write_settings(resolve_scene(yaml.safe_load(open("workflow_config.yaml")), "patch", "cpu"), d / "settings.json")
    steps = [("pipeline.scene", d / "settings.json", d / "scene.h5", "--sequence", "train_000"),
             ("pipeline.subdivide", d / "scene.h5", d / "subdiv.h5", "--quiet"),
             ("pipeline.simulate", "low", d / "settings.json", d / "scene.h5", d / "sim_low.h5", "--quiet")]
    steps += [("pipeline.simulate", level, d / "settings.json", d / "scene.h5", d / "subdiv.h5", d / "sim_low.h5",
               d / f"sim_{level}.h5", "--quiet") for level in ("high", "free")]
    for step in steps:
        run = subprocess.run([sys.executable, "-m", *map(str, step)], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
    return d


def test_the_free_run_starts_with_the_held_one_and_drifts_from_the_low_res_run(patch):
    with h5py.File(patch / "sim_high.h5") as held, h5py.File(patch / "sim_free.h5") as free:
        assert (held.attrs["level"], free.attrs["level"]) == ("high", "free")
        np.testing.assert_array_equal(free["positions"][0], held["positions"][0])
        assert np.isfinite(free["positions"][()]).all()
        assert held["harmonic_residual"][()].max() < 1e-5
        assert free["harmonic_residual"][()].max() > 100 * held["harmonic_residual"][()].max()


def test_each_solver_the_stage_times_gives_a_finite_ms_per_frame_after_the_first(patch):
    settings = read_settings(patch / "settings.json")
    sequence = TimedSequence(str(patch / "scene.h5"), str(patch / "sim_low.h5"))
    with h5py.File(patch / "sim_low.h5") as f:
        n_frames = len(f["positions"])
    times = solve_ms(simulation_settings(settings), "free",
                     (sequence.scene, str(patch / "subdiv.h5"), sequence.sim_low), "cpu", None)
    assert times.shape == (n_frames - 2,) and np.all(np.isfinite(times) & (times > 0))
    low = low_res_ms(settings, (1, 3), sequence, "cpu")
    assert low.frame_kernel == "sweeps" and np.isnan(low.other_ms)        # the CPU: the scene's kernel, once
    for ms in (low.ms, free_high_res_ms(settings, str(patch / "subdiv.h5"), sequence, "cpu")):
        assert np.isfinite(ms) and ms > 0

