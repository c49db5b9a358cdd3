"""A scene's sequences: names and roles, the clips each plays (a held-out clip never in a training sequence, BVH
entries compared by file and window), and the sequences a garment scene builds from them."""
import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.core.config import resolve_scene
from scenes.registry import build_rest, build_scene
from scenes.sequences import (clip_key, held_out_clips, parse_sequence_name, sequence_bvh_files, sequence_clips,
                              sequence_names, training_clips)

CONFIG = yaml.safe_load(open("workflow_config.yaml"))
CMU_WALK = Path(__file__).resolve().parents[3] / "shared" / "mocap" / "cmu_131_01_walk.bvh"


def pants(**mannequin) -> dict:
    settings = resolve_scene(CONFIG, "pants", "cpu")
    settings["drivers"]["mannequin"].update(mannequin)
    return settings


def test_names_list_training_sequences_then_one_per_held_out_clip():
    settings = pants(test_clips=["walk", "karate"])
    settings["sequences"] = 3
    assert sequence_names(settings) == ["train_000", "train_001", "train_002", "held_out_000", "held_out_001"]
    assert [parse_sequence_name(n) for n in ("train_002", "held_out_001", "train_1234")] == \
        [("train", 2), ("held_out", 1), ("train", 1234)]
    for bad in ("train_1", "test_000", "train_000/x", "held_out_00a"):
        with pytest.raises(ValueError, match="is not a sequence name"):
            parse_sequence_name(bad)
    grid = resolve_scene(CONFIG, "flag", "cpu")
    assert sequence_names(grid) == ["train_000"] and held_out_clips(grid) == []
    random_split = copy.deepcopy(settings)
    random_split["dataset"]["split"] = "random"      # nothing held out: every clip trains
    assert held_out_clips(random_split) == []
    assert training_clips(random_split) == settings["drivers"]["mannequin"]["clips"]


def test_held_out_clips_never_play_in_training_sequences():
    bvh = {"bvh": "mocap/./walk.bvh", "start": 1.0}
    settings = pants(clips=["dance", "walk", {"bvh": "mocap/walk.bvh", "start": 1.0}, {"bvh": "mocap/walk.bvh"}],
                     test_clips=["walk", bvh])
    pool = sequence_clips(settings, "train_007")
    assert pool == ["dance", {"bvh": "mocap/walk.bvh"}]      # the same file and window is the same clip
    assert clip_key(bvh) == clip_key({"bvh": "mocap/walk.bvh", "start": 1.0}) != clip_key({"bvh": "mocap/walk.bvh"})
    assert sequence_clips(settings, "held_out_001") == [bvh]
    assert sequence_bvh_files(settings, "held_out_001") == ["mocap/./walk.bvh"]
    assert sequence_bvh_files(settings, "train_000") == ["mocap/walk.bvh"]
    with pytest.raises(ValueError, match="no sequence 'held_out_002'"):
        sequence_clips(settings, "held_out_002")


@pytest.fixture(scope="module")
def built():
    settings = pants()
    return settings, {name: build_scene(settings, name) for name in ("train_000", "train_001", "held_out_000")}


def test_built_sequences_share_the_garment_and_differ_in_motion(built):
    settings, scenes = built
    rest = build_rest(settings)
    for scene in scenes.values():
        np.testing.assert_array_equal(scene.rest.vertices, rest.vertices)
        np.testing.assert_array_equal(scene.pins.ids, rest.pin_ids)
        assert scene.n_frames == settings["frames"]
    a, b = (scenes[n].mannequin.clips.motion.joint_angles for n in ("train_000", "train_001"))
    assert np.abs(a - b).max() > 0.1
    # every sequence starts with the same settle frames at rest: the cloth does the same there in all of them
    settle = settings["drivers"]["mannequin"]["settle_frames"]
    for scene in scenes.values():
        np.testing.assert_array_equal(scene.pins.targets[:settle + 1], scenes["train_000"].pins.targets[:settle + 1])


def test_training_programs_draw_from_the_training_clips_only(built):
    settings, scenes = built
    training = set(training_clips(settings))
    assert training == {"dance", "karate", "random"}
    for name in ("train_000", "train_001"):
        assert set(scenes[name].mannequin.clips.names[1:]) <= training and scenes[name].mannequin.program
    held = scenes["held_out_000"].mannequin
    assert held.clips.names == ("settle", "walk") and held.program == ()


def test_a_sequence_does_not_depend_on_how_many_there_are():
    few, many = pants(), pants()
    few["sequences"], many["sequences"] = 2, 9
    assert sequence_names(many)[:2] == sequence_names(few)[:2]
    one, other = build_scene(few, "train_001"), build_scene(many, "train_001")
    np.testing.assert_array_equal(one.mannequin.clips.motion.joint_angles, other.mannequin.clips.motion.joint_angles)


def test_a_missing_or_unmappable_bvh_names_the_file(tmp_path):
    settings = pants(test_clips=[{"bvh": str(tmp_path / "absent.bvh")}])
    with pytest.raises(ValueError, match=f"^{tmp_path / 'absent.bvh'}: BVH file does not exist"):
        build_scene(settings, "held_out_000")
    flat = tmp_path / "stick.bvh"
    flat.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 3 Zrotation Xrotation Yrotation\n"
                    "\tEnd Site\n\t{\n\t\tOFFSET 0 1.7 0\n\t}\n}\nMOTION\nFrames: 2\nFrame Time: 0.01\n0 0 0\n0 0 0\n")
    settings = pants(test_clips=[{"bvh": str(flat)}])
    with pytest.raises(ValueError, match=f"^{flat}: cannot map BVH 'stick' onto the mannequin: no joint for chest"):
        build_scene(settings, "held_out_000")


@pytest.mark.skipif(not CMU_WALK.is_file(), reason=f"the shared CMU clip is not at {CMU_WALK}")
def test_a_bvh_test_clip_is_a_held_out_sequence_of_its_own_length():
    settings = pants(test_clips=[{"bvh": str(CMU_WALK), "start": 4.5, "end": 7.0}])
    scene = build_scene(settings, "held_out_000")
    settle = settings["drivers"]["mannequin"]["settle_frames"]
    assert scene.n_frames == settle + 151                       # 2.5 s at 60 fps, both ends included
    assert scene.mannequin.clips.names == ("settle", "bvh:cmu_131_01_walk@4.5-7")
    root = scene.mannequin.clips.motion.root_position
    assert root[-1, 2] - root[settle, 2] > 1.0                   # it walks forward
