"""A motion library's windows start from the cloth settled once at rest (issue 35 item 3): the scene's settle
sequence is simulated at both levels, and each window's runs start from their last frames instead of settling
the same cloth on the same still body again. What makes that sound: the window's cloth is settled when its clip
starts (still and untangled, at both levels, the high-res one held to the low-res one), and a window's runs start
exactly where the settle runs end. A real clip of the shared CMU library on the tiny pants; skipped where the
library is absent."""
from __future__ import annotations

import h5py
import numpy as np
import pytest
import yaml

from pipeline import scene as scene_stage
from pipeline import simulate, subdivide
from pipeline.artifacts.scene import read_sequence, write_dropped_scene
from pipeline.core.config import LEARNING_ONLY, read_settings, resolve_scene, simulation_settings, write_settings
from pipeline.core.h5 import dropped_reason
from pipeline.solvers.xpbd import tangle_check
from scenes.registry import build_rest
from stage_inputs import stage
from workflow_runs import REPO, tiny_pants

SHARED = REPO.parent / "shared" / "mocap" / "cmu"
WINDOW = "train_003-03-01_w00"          # the first second of a walk on uneven terrain
SETTLE, BLEND, HOLD = 100, 30, 100        # frames: the CPU profile's settle and blend, a hold


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The tiny pants' settle runs and one window's, made by the stages as the workflow runs them."""
    if not SHARED.is_dir():
        pytest.skip(f"the shared CMU library is not at {SHARED}")
    root = tmp_path_factory.mktemp("settled")
    config = yaml.safe_load(tiny_pants(root, sequences=0).read_text())
    pants = config["profiles"]["cpu"]["scenes"]["pants"]
    pants["solver"] = {"substeps": 4, "iterations": 30}         # the CPU profile's budget
    pants["drivers"]["mannequin"].update(
        settle_frames=SETTLE, blend_frames=BLEND,
        library={"dir": str(SHARED), "manifest": "MANIFEST.tsv", "fps_column": "cmu_capture_fps",
                 "frame_rates": {}, "window": 1.0, "hold_frames": HOLD})
    pants["library_windows"] = {"include": ["003/03_01.bvh.gz"], "exclude": [], "max_clips": 0,
                                "held_out_subjects": []}
    settings = root / "simulation.json"
    write_settings(simulation_settings(resolve_scene(config, "pants", "cpu")), settings)
    settle, window = root / "settle", root / "sequences" / WINDOW
    for folder, name in ((settle, "settle"), (window, WINDOW)):
        stage(scene_stage.main, settings, folder / "scene.h5", "--sequence", name)
    stage(subdivide.main, settle / "scene.h5", root / "subdiv.h5", "--settings", settings)
    for folder, settled in ((settle, ()), (window, ("--settled", settle / "sim_low.h5"))):
        stage(simulate.main, "low", settings, folder / "scene.h5", folder / "sim_low.h5", *settled, "--quiet")
    for folder, settled in ((settle, ()), (window, ("--settled", settle / "sim_high.h5"))):
        stage(simulate.main, "high", settings, folder / "scene.h5", root / "subdiv.h5", folder / "sim_low.h5",
              folder / "sim_high.h5", *settled, "--quiet")
    return root, settings



def positions(path) -> np.ndarray:
    with h5py.File(path) as f:
        return f["positions"][()].astype(np.float64)


def test_a_window_starts_where_the_settle_runs_end(runs):
    root, _ = runs
    window = root / "sequences" / WINDOW
    for level in ("low", "high"):
        settled, played = positions(root / "settle" / f"sim_{level}.h5"), positions(window / f"sim_{level}.h5")
        assert len(settled) == SETTLE + 1           # frame 0 at rest, then SETTLE frames of settling
        np.testing.assert_array_equal(played[0], settled[-1])
    # The window's lead-in is the blend and the hold: the settle at rest is not stepped again.
    assert read_sequence(window / "scene.h5").settle_frames == BLEND + HOLD


def test_the_cloth_is_settled_when_the_clip_starts(runs):
    """Still: in the last frame of the hold, after the blend has swung the cloth about at metres a second, its
    vertices move at a small share of the speed gravity gives a free vertex in one frame (g dt = 16 cm/s): RMS below
    a tenth, every vertex below a half (measured 2026-11-26: RMS 7 mm/s, max 4 cm/s at high res 10 frames before).
    Untangled: no more edges stretched than the tangle check allows, all through the lead-in. And the high-res
    cloth is held to the low-res one all along (the settled high-res cloth was held to the settled low-res one)."""
    root, _ = runs
    window = root / "sequences" / WINDOW
    lead_in = BLEND + HOLD
    with h5py.File(window / "sim_high.h5") as f:
        residual = f["harmonic_residual"][: lead_in + 1]
    assert residual.max() < 1e-3, residual.max()
    free_fall = 9.81 / 60
    for level in ("low", "high"):
        x = positions(window / f"sim_{level}.h5")
        with h5py.File(window / f"sim_{level}.h5") as f:
            rest, faces = f["rest_vertices"][()], f["faces"][()]
        speed = np.linalg.norm(x[1:lead_in + 1] - x[:lead_in], axis=2) * 60      # (lead-in frames, V) m/s
        assert speed[:BLEND + 10].max() > 1.0, level          # the blend did move the cloth about
        assert np.sqrt((speed[-1] ** 2).mean()) < 0.1 * free_fall, (level, np.sqrt((speed[-1] ** 2).mean()))
        assert speed[-1].max() < 0.5 * free_fall, (level, speed[-1].max())
        assert tangle_check(rest, faces)(x[: lead_in + 1]) == "", level


def test_a_window_without_its_settle_run_is_refused(runs, tmp_path, capsys):
    root, settings = runs
    window = root / "sequences" / WINDOW
    with pytest.raises(SystemExit):
        stage(simulate.main, "low", settings, window / "scene.h5", tmp_path / "sim_low.h5", "--quiet")
    said = capsys.readouterr().err
    assert f"{window / 'scene.h5'}: starts from the scene's settled cloth" in said and "--settled" in said
    assert not (tmp_path / "sim_low.h5").exists()


def test_a_batch_that_begins_with_a_dropped_window_steps_the_others_as_before(runs, tmp_path):
    """Shards of windows are batched by length, so one may begin with a window dropped at the scene stage (whose
    scene file holds no mesh): the others are stepped, from the settled cloth, exactly as alone."""
    root, settings = runs
    window = root / "sequences" / WINDOW
    dropped = tmp_path / "dropped" / "scene.h5"
    dropped.parent.mkdir()
    scene_settings = read_settings(settings, unread=LEARNING_ONLY)
    write_dropped_scene(dropped, build_rest(scene_settings), "train_003-03-01_w01", "cannot be played", None,
                        scene_settings)
    stage(simulate.main, "low", settings, dropped, dropped.parent / "sim_low.h5", window / "scene.h5",
          tmp_path / "sim_low.h5", "--settled", root / "settle" / "sim_low.h5", "--quiet")
    assert dropped_reason(dropped.parent / "sim_low.h5").endswith("dropped: cannot be played")
    np.testing.assert_array_equal(positions(tmp_path / "sim_low.h5"), positions(window / "sim_low.h5"))
