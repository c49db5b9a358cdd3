"""experiments.tradeoff.grid: the trade-off's budgets, high-res runs, folders, settings overlays and the stage's
argument list, from a hand-made scene's settings (the workflow's plan of them: test_workflow_tradeoff.py)."""
import copy

import pytest

from experiments.tradeoff import grid

SCENE = "cloth"
SEQUENCES = ["train_000", "held_out_000"]


def scene_settings(shard=1, **tradeoff):
    """A scene simulated at 2 substeps x 10 iterations, harmonic projection every substep, with a small grid."""
    block = {"substeps": [1, 2], "matched": [1], "matched_widths": [], "widths": [0.5], "epochs": 3,
             "high_res_budgets": [[1, 5]], "harmonic_every": [], **tradeoff}
    return {"solver": {"substeps": 2, "iterations": 10, "relaxation": 1.0}, "high_res": {"harmonic_every": "substep"},
            "network": {"conv": "RC9", "width": 0.25}, "training": {"epochs": 8, "batch_size": 4},
            "operators": {"levels": 6}, "evaluation": {"render_frames": 3}, "device": "cpu",
            "sequences": 1, "shard": shard, "study": {"width": None}, "applications": {}, "tradeoff": block}


def test_the_budgets_are_the_grids_and_the_matched_ones_once_in_order_and_the_scenes_own_has_no_matched_network():
    settings = scene_settings(substeps=[8, 2, 1], matched=[4, 2, 4])
    assert grid.budgets(settings) == ["1", "2", "4", "8"]
    assert grid.matched_budgets(settings) == ["4"]        # 2 is the scene's own: its network is the scene's


def test_a_budget_of_other_iterations_is_named_nxi_and_at_the_scenes_iterations_n():
    """The scene: 2 substeps x 10 iterations. [1, 4] is its own budget "1x4"; [1, 10] and [2, 10] are 1 and the
    scene's own 2, whatever way they are written."""
    settings = scene_settings(substeps=[[1, 4], 1, [2, 10]], matched=[[1, 4], [2, 10], [1, 10]])
    assert grid.budgets(settings) == ["1x4", "1", "2"]
    assert grid.matched_budgets(settings) == ["1x4", "1"]
    assert [grid.parse_budget_name(settings, name) for name in ("1x4", "1", 2)] == [(1, 4), (1, 10), (2, 10)]
    for name, solver in (("1x4", (1, 4)), ("1", (1, 10))):
        for overlay in (grid.point_settings(settings, name), grid.point_simulation(settings, name)):
            assert (overlay["solver"]["substeps"], overlay["solver"]["iterations"]) == solver
            assert overlay["solver"]["relaxation"] == 1.0          # the rest of the scene's solver kept
    assert grid.matched_settings(settings, "1x4", 0.5)["solver"]["iterations"] == 4
    assert grid.point_dataset(SCENE, settings, "1x4") == "results/cloth/tradeoff/s1x4/dataset.h5"
    assert grid.point_dataset(SCENE, settings, "2x10") == "results/cloth/dataset.h5"       # the scene's own
    words = grid.stage_arguments(SCENE, settings, SEQUENCES)
    assert words[words.index("--point"):words.index("--point") + 3] == [
        "--point", "1x4", "results/cloth/tradeoff/s1x4/sequences/train_000/sim_low.h5"]
    assert ["--matched", "1x4", "results/cloth/tradeoff/s1x4/matched/eval.h5",
            "results/cloth/tradeoff/s1x4/matched/model.pt"] == words[words.index("--matched"):][:4]


def test_the_high_res_runs_keep_config_order_once_each_and_leave_the_reference_out():
    settings = scene_settings(high_res_budgets=[[1, 5], [2, 10], [3, 7], [1, 5]],
                              harmonic_every=["iteration", "substep"])
    assert grid.reference_run(settings) == (2, 10, "substep")
    assert grid.high_res_runs(settings) == [(1, 5, "substep"), (3, 7, "substep"), (2, 10, "iteration")]


def test_the_scenes_own_budget_reuses_the_scenes_runs_and_dataset():
    settings = scene_settings()
    assert grid.low_runs(SCENE, settings, SEQUENCES, 2) == [
        "results/cloth/sequences/train_000/sim_low.h5", "results/cloth/sequences/held_out_000/sim_low.h5"]
    assert grid.point_dataset(SCENE, settings, 2) == "results/cloth/dataset.h5"
    assert grid.low_runs(SCENE, settings, SEQUENCES, 1) == [
        "results/cloth/tradeoff/s1/sequences/train_000/sim_low.h5",
        "results/cloth/tradeoff/s1/sequences/held_out_000/sim_low.h5"]
    assert grid.point_dataset(SCENE, settings, 1) == "results/cloth/tradeoff/s1/dataset.h5"


def test_each_network_is_the_scenes_model_a_width_folder_or_the_budgets_matched_one():
    assert grid.network_model(SCENE, 1, "scene") == "results/cloth/model.pt"
    assert grid.network_model(SCENE, 1, "matched") == "results/cloth/tradeoff/s1/matched/model.pt"
    assert grid.network_model(SCENE, "1", "matched_w0.25") == "results/cloth/tradeoff/s1/matched_w0.25/model.pt"
    assert grid.matched_nets(scene_settings(matched_widths=[0.25, 1])) == ["matched", "matched_w0.25", "matched_w1"]
    assert grid.network_model(SCENE, "1", "w0.5") == "results/cloth/tradeoff/w0.5/model.pt"
    assert grid.scene_trained_nets(scene_settings(widths=[0.5, 0.125, 1])) == ["scene", "w0.5", "w0.125", "w1"]


@pytest.mark.parametrize("width, folder", [(0.5, "w0.5"), ("0.5", "w0.5"), ("0.50", "w0.5"), (1, "w1"),
                                           ("1.0", "w1"), (0.125, "w0.125"), (1e-5, "w1e-05")])
def test_a_width_folder_is_the_same_from_the_config_and_from_a_wildcard(width, folder):
    assert grid.width_folder(width) == folder


def test_the_argument_list_of_a_small_grid():
    """The first sequence the stage times the solvers on; budget 1 (re-simulated, a smaller network, a matched
    one) and the scene's own 2, each with its first sequence's run (its frames time Loop subdivision); one high-res
    run."""
    words = grid.stage_arguments(SCENE, scene_settings(), SEQUENCES)
    assert words == [
        "--solve-timing", "results/cloth/sequences/train_000/scene.h5", "results/cloth/sequences/train_000/sim_low.h5",
        "--point", "1", "results/cloth/tradeoff/s1/sequences/train_000/sim_low.h5",
        "--eval", "1", "results/cloth/tradeoff/s1/scene/eval.h5", "results/cloth/model.pt",
        "--eval", "1", "results/cloth/tradeoff/s1/w0.5/eval.h5", "results/cloth/tradeoff/w0.5/model.pt",
        "--matched", "1", "results/cloth/tradeoff/s1/matched/eval.h5", "results/cloth/tradeoff/s1/matched/model.pt",
        "--point", "2", "results/cloth/sequences/train_000/sim_low.h5",
        "--eval", "2", "results/cloth/tradeoff/s2/scene/eval.h5", "results/cloth/model.pt",
        "--eval", "2", "results/cloth/tradeoff/s2/w0.5/eval.h5", "results/cloth/tradeoff/w0.5/model.pt",
        "--high-res", "1", "5", "substep", "results/cloth/tradeoff/h1x5_substep/sequences/train_000/sim_high.h5",
        "results/cloth/tradeoff/h1x5_substep/sequences/held_out_000/sim_high.h5"]


def test_each_matched_budget_has_the_scenes_recipe_then_each_matched_width_and_the_scenes_own_none():
    words = grid.stage_arguments(SCENE, scene_settings(substeps=[1], matched=[1, 2], matched_widths=[0.25]),
                                 SEQUENCES)
    matched = [words[i + 1:i + 4] for i, word in enumerate(words) if word == "--matched"]
    assert matched == [
        ["1", "results/cloth/tradeoff/s1/matched/eval.h5", "results/cloth/tradeoff/s1/matched/model.pt"],
        ["1", "results/cloth/tradeoff/s1/matched_w0.25/eval.h5", "results/cloth/tradeoff/s1/matched_w0.25/model.pt"]]


@pytest.mark.parametrize("shard", [1, 2])
def test_the_stage_inputs_are_the_files_of_its_arguments_each_once(shard):
    settings = scene_settings(shard=shard, substeps=[1, 4], matched=[1, 2, 4], widths=[0.5, 0.125],
                              matched_widths=[0.25], high_res_budgets=[[1, 5], [2, 10]], harmonic_every=["iteration"])
    words = grid.stage_arguments(SCENE, settings, SEQUENCES)
    inputs = grid.stage_inputs(SCENE, settings, SEQUENCES)
    assert len(inputs) == len(set(inputs))
    assert set(inputs) == {word for word in words if word.startswith("results/")}


def test_a_sharded_scene_times_each_high_res_run_by_its_first_sequence_alone():
    """The budgets and the reference are timed by the stage itself (--solve-timing); the high-res rows by a timing
    run each of the first sequence alone."""
    settings = scene_settings(shard=2, harmonic_every=["iteration"])
    runs = [(1, 5, "substep"), (2, 10, "iteration")]
    assert grid.high_res_runs(settings) == runs
    timings = grid.high_res_timings(SCENE, settings)
    assert list(timings) == runs                                  # no reference: the stage times the free run
    words = grid.stage_arguments(SCENE, settings, SEQUENCES)
    assert [words[i + 3] for i, word in enumerate(words) if word == "--point"] == ["--eval", "--eval"]   # one each
    timing_words = words[words.index("--high-res-timing"):]
    assert timing_words == [
        "--high-res-timing", "1", "5", "substep", "results/cloth/tradeoff/h1x5_substep/timing/sim_high.h5",
        "--high-res-timing", "2", "10", "iteration", "results/cloth/tradeoff/h2x10_iteration/timing/sim_high.h5"]
    assert grid.high_res_timings(SCENE, scene_settings(shard=1)) == {}


def test_a_motion_librarys_window_is_timed_from_the_scenes_settle_runs():
    words = grid.stage_arguments(SCENE, scene_settings(), ["train_001-01-01_w00", "held_out_000"])
    assert words[:6] == ["--solve-timing", "results/cloth/sequences/train_001-01-01_w00/scene.h5",
                         "results/cloth/sequences/train_001-01-01_w00/sim_low.h5", "--settled",
                         "results/cloth/settle/sim_low.h5", "results/cloth/settle/sim_high.h5"]


def test_a_high_res_file_from_wildcards_is_the_one_from_the_config():
    assert (grid.high_res_file(SCENE, ("1", "5", "substep"), "held_out_000")
            == grid.high_res_files(SCENE, SEQUENCES, (1, 5, "substep"))[1]
            == "results/cloth/tradeoff/h1x5_substep/sequences/held_out_000/sim_high.h5")


def test_each_overlay_changes_only_its_keys_and_leaves_out_what_its_file_never_holds():
    settings = scene_settings()
    before = copy.deepcopy(settings)
    workflow_only = {"sequences", "shard", "study", "applications", "tradeoff"}
    learning_only = {"operators", "network", "training", "evaluation"}
    scene_file = {key: value for key, value in settings.items() if key not in workflow_only}
    simulation_file = {key: value for key, value in scene_file.items() if key not in learning_only}

    point = grid.point_settings(settings, "1")
    assert point == {**scene_file, "solver": {**settings["solver"], "substeps": 1}}
    assert grid.point_simulation(settings, "1") == {**simulation_file, "solver": {**settings["solver"], "substeps": 1}}
    assert grid.network_settings(settings, "0.125") == {**scene_file, "network": {"conv": "RC9", "width": 0.125},
                                                        "training": {"epochs": 3, "batch_size": 4}}
    assert grid.matched_settings(settings, "1", "0.5") == {**point, "network": {"conv": "RC9", "width": 0.5}}
    assert grid.high_res_simulation(settings, ("4", "20", "iteration")) == {
        **simulation_file, "solver": {"substeps": 4, "iterations": 20, "relaxation": 1.0},
        "high_res": {"harmonic_every": "iteration"}}
    assert settings == before                                     # the scene's settings are not touched
