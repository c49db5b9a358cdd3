"""pipeline.workflow_paths: what a scene's targets stand for, its sequences' files, the BVH check, the batch rules'
names, the wildcard patterns and the applications' paths, from hand-made settings (the workflow's plan of them:
test_workflow.py, test_workflow_applications.py)."""
import json
import re
import subprocess
import sys

import pytest

from pipeline import workflow_paths
from pipeline.core.errors import PipelineError

SEQUENCES = ["train_000", "train_001", "held_out_000"]


def test_one_of_matches_each_name_exactly_and_nothing_else():
    pattern = workflow_paths.one_of(["patch", "my.scene", "a+b"])
    for name in ("patch", "my.scene", "a+b"):
        assert re.fullmatch(pattern, name)
    for name in ("myxscene", "aab", "patch2", "", "patch|my"):
        assert not re.fullmatch(pattern, name), name
    nothing = workflow_paths.one_of([])
    assert not any(re.fullmatch(nothing, name) for name in ("", "patch", "(?!)"))


@pytest.mark.parametrize("scene, name", [("pants", "simulate_low_batch_pants_003"),
                                         ("my-scene.v2", "simulate_low_batch_my_scene_v2_003")])
def test_a_batch_rule_name_is_an_identifier_per_scene_and_shard(scene, name):
    assert workflow_paths.batch_rule_name("simulate_low", scene, 3) == name and name.isidentifier()


def test_a_scenes_target_is_its_sequences_runs_then_its_products():
    products = workflow_paths.scene_products("cloth", SEQUENCES)
    assert products[:6] == [f"results/cloth/sequences/{seq}/{name}" for seq in SEQUENCES
                            for name in ("sim_low.h5", "sim_high.h5")]
    assert products[6:] == [f"results/cloth/{name}" for name in ("operators.h5", "dataset.h5", "model.pt",
                                                                 "train.h5", "eval.h5", "report.md", "report.html",
                                                                 "renders", "videos", "export")]
    assert workflow_paths.sequence_files("cloth", SEQUENCES, "scene.h5") == [
        "results/cloth/sequences/train_000/scene.h5", "results/cloth/sequences/train_001/scene.h5",
        "results/cloth/sequences/held_out_000/scene.h5"]


def test_a_hand_scenes_sequences_are_fem_runs_and_its_operators_are_built_on_its_skin():
    hand, cloth = {"mesh": {"generator": "hand"}}, {"mesh": {"generator": "garment"}}
    products = workflow_paths.scene_products("hand", SEQUENCES, workflow_paths.sequence_products(hand))
    assert products[:3] == [f"results/hand/sequences/{seq}/fem.h5" for seq in SEQUENCES]
    assert products[3:] == workflow_paths.scene_products("hand", [])
    assert workflow_paths.sequence_products(cloth) == ("sim_low.h5", "sim_high.h5")
    assert workflow_paths.operators_mesh("hand", hand) == "results/hand/hand.h5"
    assert workflow_paths.operators_mesh("pants", cloth) == "results/pants/subdiv.h5"


def test_a_users_hand_is_a_hand_scene_whose_two_files_must_exist_and_a_missing_one_is_named(tmp_path):
    obj, bones = tmp_path / "hand.obj", tmp_path / "bones.yaml"
    mine = {"mesh": {"generator": "hand_file", "file": str(obj), "bones": str(bones)}}
    assert workflow_paths.is_hand(mine) and workflow_paths.operators_mesh("mine", mine) == "results/mine/hand.h5"
    assert workflow_paths.hand_files(mine) == [str(obj), str(bones)]
    assert workflow_paths.hand_files({"mesh": {"generator": "hand"}}) == []
    obj.write_text("v 0 0 0")
    with pytest.raises(PipelineError, match=f"{re.escape(str(bones))}: hand file of scene 'mine' \\(mesh.bones\\) "
                                            f"does not exist"):
        workflow_paths.check_user_files("mine", mine)
    bones.write_text("joints: []")
    workflow_paths.check_user_files("mine", mine)


def garment_settings(clips, test_clips):
    return {"mesh": {"generator": "garment"}, "dataset": {"split": "held_out"}, "sequences": 1,
            "drivers": {"mannequin": {"clips": clips, "test_clips": test_clips}}}


def test_every_bvh_file_a_scene_plays_must_exist_and_a_missing_one_is_named(tmp_path):
    walk, jump = tmp_path / "walk.bvh", tmp_path / "jump.bvh"
    walk.write_text("HIERARCHY")
    settings = garment_settings(["dance", {"bvh": str(jump)}], [{"bvh": str(walk), "start": 0.5}])
    with pytest.raises(PipelineError, match=f"{re.escape(str(jump))}: BVH file of scene 'cloth' does not exist"):
        workflow_paths.check_bvh_files("cloth", settings, ["train_000", "held_out_000"])
    jump.write_text("HIERARCHY")
    workflow_paths.check_bvh_files("cloth", settings, ["train_000", "held_out_000"])
    grid = {"mesh": {"generator": "grid"}, "drivers": {}}          # a grid scene plays no clip
    workflow_paths.check_bvh_files("patch", grid, ["train_000"])


def application_scene(generator="garment", pose_operators=None):
    pose = {"network": {"arch": "U8 U3"}, **({"operators": pose_operators} if pose_operators else {})}
    return {"mesh": {"generator": generator}, "operators": {"levels": 6, "conv": ["RC9"]},
            "network": {"arch": "D8 D8"}, "sequences": 2, "shard": 1, "study": {}, "tradeoff": {},
            "applications": {"pose": pose, "pca": {"components": [16, 4]}}}


def test_an_application_reads_the_scenes_operators_unless_its_own_settings_differ():
    assert workflow_paths.application_of("pca/k16") == "pca" and workflow_paths.application_of("pose") == "pose"
    assert workflow_paths.application_operators("cloth", application_scene(), "pose") == "results/cloth/operators.h5"
    assert workflow_paths.application_operators("cloth", application_scene(), "pca") == "results/cloth/operators.h5"
    deeper = application_scene(pose_operators={"levels": 8})
    assert workflow_paths.application_operators("cloth", deeper, "pose") == "results/cloth/pose/operators.h5"
    assert workflow_paths.application_operators("cloth", deeper, "pca") == "results/cloth/operators.h5"


def test_the_pca_target_is_a_folder_per_component_count_then_its_table():
    settings = application_scene()
    assert workflow_paths.pca_model_dirs(settings) == ["pca/k16", "pca/k4"]
    assert workflow_paths.pca_summary_arguments("cloth", settings) == [
        "--model", "16", "results/cloth/pca/k16/eval.h5", "--model", "4", "results/cloth/pca/k4/eval.h5"]
    products = workflow_paths.application_products("cloth", settings, "pca")
    assert products[-1] == "results/cloth/pca/report.md" and len(products) == 2 * 9 + 1
    assert products[:2] == ["results/cloth/pca/k16/dataset.h5", "results/cloth/pca/k16/model.pt"]
    assert workflow_paths.application_products("cloth", settings, "pose")[0] == "results/cloth/pose/dataset.h5"


def test_a_scene_without_a_mannequin_has_no_pose_target_but_a_pca_one():
    grid = application_scene(generator="grid")
    with pytest.raises(PipelineError, match="results/patch/pose/: scene 'patch' has no mannequin"):
        workflow_paths.application_products("patch", grid, "pose")
    assert workflow_paths.application_products("patch", grid, "pca")[-1] == "results/patch/pca/report.md"


def test_the_workflows_helper_modules_add_no_import_to_the_snakefiles_own():
    """The Snakefile imports them at every start (a dry run, every job's start): beyond the config module it
    imports anyway, they bring in nothing but themselves, and no torch or Warp."""
    modules = ["pipeline.workflow_paths", "experiments.tradeoff.grid", "experiments.study.points",
               "experiments.multi.garments"]
    code = ("import json, sys\nimport pipeline.core.config\nbefore = set(sys.modules)\n"
            f"for name in {modules!r}: __import__(name)\n"
            "print(json.dumps([sorted(set(sys.modules) - before), 'torch' in sys.modules or 'warp' in sys.modules]))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    added, heavy = json.loads(run.stdout)
    packages = {"experiments", "experiments.tradeoff", "experiments.study", "experiments.multi"}
    assert set(added) == set(modules) | packages and not heavy


def test_a_library_that_cannot_be_listed_is_one_error_naming_the_scene_and_the_folder(tmp_path):
    from scenes.sequences import sequence_names
    settings = {"sequences": 0, "mesh": {"generator": "garment"}, "library_windows": {"include": ["*"], "exclude": [], "max_clips": 0,
                                                    "held_out_subjects": []},
                "drivers": {"mannequin": {"library": {"dir": str(tmp_path / "absent"), "manifest": None,
                                                      "fps_column": None, "frame_rates": {}, "window": 10.0,
                                                      "hold_frames": 100}}}}
    with pytest.raises(PipelineError, match=f"scene 'pants': {re.escape(str(tmp_path / 'absent'))}: motion library "
                                            f"folder does not exist"):
        workflow_paths.sequences_or_error("pants", lambda: sequence_names(settings))
    assert workflow_paths.sequences_or_error("pants", lambda: ["train_000"]) == ["train_000"]


def test_the_train_job_runs_its_ranks_under_torchrun_with_a_gpu_and_a_share_of_the_threads_each():
    one = {"device": "cuda:0", "training": {"ranks": 1}}
    four = {"device": "cuda:0", "training": {"ranks": 4}}
    assert workflow_paths.train_launcher(one) == [] and workflow_paths.train_gpus(one) == 1
    assert workflow_paths.train_launcher(four) == ["-m", "torch.distributed.run", "--standalone",
                                                   "--nproc_per_node=4"]
    assert workflow_paths.train_gpus(four) == 4 and workflow_paths.train_gpus({**four, "device": "cpu"}) == 0
    # With two jobs a GPU, ranks take their GPUs whole (both slots each); one process takes one slot.
    assert workflow_paths.train_gpus(four, 2) == 8 and workflow_paths.train_gpus(one, 2) == 1
    assert [workflow_paths.rank_threads(four, t) for t in (1, 4, 16, 17)] == [1, 1, 4, 4]
    assert workflow_paths.rank_threads(one, 16) == 16


@pytest.mark.parametrize("folder", workflow_paths.CLOTH_EXPERIMENTS)
def test_a_cloth_experiment_of_a_hand_scene_is_one_error_naming_the_hands_target(folder):
    settings = {"hand": {"mesh": {"generator": "hand"}}, "pants": {"mesh": {"generator": "garment"}}}
    workflow_paths.check_targets(["results/hand/", "results/pants/" + folder, f"results/hand/{folder}x"], settings)
    with pytest.raises(PipelineError, match=rf"^results/hand/{folder}/: '{folder}' is made from a cloth scene's "
                                            r"runs, .* its target is results/hand/$"):
        workflow_paths.check_targets([f"results/hand/{folder}/"], settings)
