"""experiments.study.points: each count's sequences, the networks' step budget and width, the points and the
stage's arguments, from a hand-made scene's settings (the workflow's plan of them: test_workflow.py)."""
import pytest

from experiments.study import points
from pipeline.core.errors import PipelineError

SEQUENCES = ["train_000", "train_001", "train_002", "train_003", "held_out_000", "held_out_001"]


def scene_settings(study_epochs=None, study_width=None, train_frames=(), oracle=False, counts=(1, 6)):
    """Four training sequences, 6 epochs, a quarter-width network; a study of two counts and two variants."""
    return {"sequences": 4, "training": {"epochs": 6}, "network": {"width": 0.25},
            "study": {"sequence_counts": list(counts), "train_frames": list(train_frames), "oracle": oracle,
                      "epochs": study_epochs, "width": study_width,
                      "variants": {"positions": {"inputs": ["position"]}, "body": {"inputs": ["position", "body"]}}}}


@pytest.mark.parametrize("count, training", [(1, ["train_000"]), (2, ["train_000", "train_001"]),
                                             (6, [f"train_{i:03d}" for i in range(6)])])
def test_a_count_trains_on_the_first_sequences_made_alike_beyond_the_scenes_and_keeps_every_held_out_one(count,
                                                                                                       training):
    assert points.study_sequences(SEQUENCES, count) == [*training, "held_out_000", "held_out_001"]


def test_a_scene_without_held_out_sequences_gives_training_sequences_only():
    assert points.study_sequences(["train_000", "train_001"], 3) == ["train_000", "train_001", "train_002"]


@pytest.mark.parametrize("study_epochs, expected", [
    (None, {1: 24, 2: 12, 3: 8, 4: 6, 5: 5, 24: 1, 100: 1}),       # the scene's 6 epochs x 4 sequences = 24
    (2, {1: 8, 2: 4, 3: 3, 4: 2, 6: 1, 100: 1})])                  # 2 epochs x 4 = 8; 8 / 3 rounds to 3
def test_every_count_takes_as_many_optimiser_steps_as_the_epochs_over_the_scenes_sequences_at_least_one_epoch(
        study_epochs, expected):
    settings = scene_settings(study_epochs=study_epochs)
    assert {count: points.training_epochs(settings, count) for count in expected} == expected


def test_the_width_is_the_studys_or_the_scenes_networks():
    assert points.network_width(scene_settings()) == 0.25
    assert points.network_width(scene_settings(study_width=0.125)) == 0.125


def test_the_points_go_by_count_then_variant_and_the_arguments_name_each():
    assert points.points("cloth", scene_settings()) == [
        ("n1", "positions", "results/cloth/study/n1/positions/eval.h5"),
        ("n1", "body", "results/cloth/study/n1/body/eval.h5"),
        ("n6", "positions", "results/cloth/study/n6/positions/eval.h5"),
        ("n6", "body", "results/cloth/study/n6/body/eval.h5")]
    assert points.stage_arguments("cloth", scene_settings())[:8] == [
        "--point", "n1", "positions", "results/cloth/study/n1/positions/eval.h5",
        "--point", "n1", "body", "results/cloth/study/n1/body/eval.h5"]
    assert len(points.stage_arguments("cloth", scene_settings())) == 16


def test_frame_points_and_the_oracle_train_on_the_scenes_dataset_at_the_scenes_budget():
    settings = scene_settings(study_epochs=3, train_frames=[1000, 30000], oracle=True, counts=[2])
    assert points.point_labels(settings) == ["n2", "f1000", "f30000", "oracle"]
    assert [points.own_dataset(label) for label in points.point_labels(settings)] == [True, False, False, False]
    assert points.training_flags(settings, "n2") == ["--epochs", "6"]            # 3 epochs x 4 / 2 sequences
    assert points.training_flags(settings, "f30000") == ["--epochs", "3", "--train-frames", "30000"]
    assert points.training_flags(settings, "oracle") == ["--epochs", "3", "--train-on", "train,held_out"]
    with pytest.raises(PipelineError, match="no point to train"):
        points.point_labels(scene_settings(counts=[]))
