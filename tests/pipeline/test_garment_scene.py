"""The scene stage for garment scenes: what the sequences share and a sequence's mannequin arrays, attachment
pins, torso frames, motion program, and the typed readers of scene.h5."""
import h5py
import numpy as np
import pytest
import yaml

from geometry.rigid import apply_rigid, apply_rigid_inverse
from geometry.rotations import quat_to_matrix
from pipeline.artifacts.scene import (read_body, read_mannequin_frames, read_rest_mesh, read_scene_drive,
                                      read_sequence, read_torso_transforms, write_scene)
from pipeline.core.config import resolve_scene, shared_settings, write_settings
from pipeline.core.errors import PipelineError
from pipeline.scene import main as scene_main
from scenes.capsules import body_signed_distance, capsules_world
from scenes.kinematics import rest_transforms
from scenes.registry import build_scene
from scenes.skeleton import default_skeleton

CONFIG = yaml.safe_load(open("workflow_config.yaml"))


def scene_datasets(settings: dict, path, sequence: str = "train_000") -> dict[str, np.ndarray]:
    """Every dataset of the scene.h5 written for a sequence of `settings`, keyed by path."""
    write_scene(path, build_scene(settings, sequence), settings)
    arrays = {}
    with h5py.File(path) as f:
        f.visititems(lambda name, obj: arrays.update({name: obj[()]}) if isinstance(obj, h5py.Dataset) else None)
    return arrays


@pytest.fixture(scope="module")
def pants(tmp_path_factory):
    settings = resolve_scene(CONFIG, "pants", "cpu")
    path = tmp_path_factory.mktemp("pants") / "scene.h5"
    return settings, scene_datasets(settings, path), path


def test_pins_start_at_rest_and_move_rigidly_with_their_part(pants):
    settings, a, _ = pants
    pins, targets = a["pins/ids"], a["pins/targets"]
    assert targets.shape == (settings["frames"], len(pins), 3) and len(pins) > 0
    assert np.abs(targets[0] - a["rest/vertices"][pins]).max() < 1e-6
    assert set(np.unique(a["pins/part"])) == {0}   # the waist band follows the pelvis
    # rigid: all pairwise distances kept, while the band does move
    d = np.linalg.norm(targets[:, :, None] - targets[:, None, :], axis=-1)
    assert np.abs(d - d[0]).max() < 1e-5
    assert np.abs(targets - targets[0]).max() > 0.05


def test_body_arrays_agree_with_the_library(pants):
    _, a, _ = pants
    skel = default_skeleton()
    ra, rb = a["capsules/radius_a"], a["capsules/radius_b"]
    ca, cb, *_ = capsules_world(skel, rest_transforms(skel))
    assert np.allclose(a["capsules/a"][0], ca, atol=1e-6) and np.allclose(a["capsules/b"][0], cb, atol=1e-6)
    assert np.allclose(ra, skel.radius_a) and np.allclose(rb, skel.radius_b)
    # the rest garment clears the rest body
    assert body_signed_distance(skel, rest_transforms(skel), a["rest/vertices"]).min() > 0
    torso = a["torso_transforms"]
    assert np.allclose(torso[:, :3, :3], quat_to_matrix(a["body/state/rotation"][:, 0]))
    assert np.allclose(torso[:, :3, 3], a["body/state/translation"][:, 0])
    # capsule velocities agree with the motion of the end points (central differences; karate's and random's
    # PCHIP keyframes are only C1, so differences at 60 fps are off by several % near a keyframe)
    fps = 1.0 / CONFIG["defaults"]["solver"]["dt"]
    fd = (a["capsules/a"][2:] - a["capsules/a"][:-2]) * fps / 2
    assert np.abs(fd - a["capsules/velocity_a"][1:-1]).max() < 0.15 * np.abs(a["capsules/velocity_a"]).max()
    assert a["pose"].shape == (len(torso), 208)
    assert np.allclose(a["skinning/weights"].sum(axis=1), 1.0, atol=1e-6)


def test_attachment_is_still_in_the_torso_frame(pants):
    _, a, _ = pants
    local = apply_rigid_inverse(a["torso_transforms"][:, None], a["pins/targets"].astype(np.float64))
    assert np.abs(local - local[0]).max() < 1e-5


def test_scene_files_round_trip_the_skeleton_and_are_deterministic(tmp_path):
    settings = resolve_scene(CONFIG, "skirt", "cpu")
    write_settings(shared_settings(settings), tmp_path / "settings.json")
    for name in ("one.h5", "two.h5"):
        scene_main([str(tmp_path / "settings.json"), str(tmp_path / name), "--sequence", "train_001"])
    scene_main([str(tmp_path / "settings.json"), str(tmp_path / "rest.h5")])
    with h5py.File(tmp_path / "one.h5") as one, h5py.File(tmp_path / "two.h5") as two, \
            h5py.File(tmp_path / "rest.h5") as rest:
        skel, _ = read_body(tmp_path / "one.h5")
        assert skel.names == default_skeleton().names and np.allclose(skel.capsule_b, default_skeleton().capsule_b)
        for name in ("rest/vertices", "pins/targets", "capsules/a", "pose", "motion/clip", "motion/program/speed"):
            assert np.array_equal(one[name][()], two[name][()])
        # the shared file: what every sequence has, and nothing that moves
        for name in ("rest/vertices", "rest/faces", "pins/ids", "pins/part", "skinning/weights", "body/capsule_a"):
            assert np.array_equal(rest[name][()], one[name][()])
        assert "pins/targets" not in rest and "motion" not in rest and "sequence" not in rest.attrs
        assert (one.attrs["sequence"], one.attrs["role"], one.attrs["frames"]) == ("train_001", "train", 210)
        program = one["motion/program"]
        names = [n.decode() for n in one["motion/clip_names"][1:]]
        assert len(program["speed"]) == len(names) and program["start"][0] == 30 and program["fade_out"][-1] == 0
    assert read_rest_mesh(tmp_path / "rest.h5")[0].shape == read_rest_mesh(tmp_path / "one.h5")[0].shape
    with pytest.raises(PipelineError, match="not the scene of a sequence"):
        read_sequence(tmp_path / "rest.h5")


def test_too_few_frames_for_the_clips_is_one_clear_error(tmp_path):
    settings = resolve_scene(CONFIG, "tshirt", "cpu")
    settings["frames"] = 60
    with pytest.raises(ValueError, match="^60 frames with 30 settle frames"):
        build_scene(settings, "held_out_000")
    write_settings(settings, tmp_path / "settings.json")
    with pytest.raises(PipelineError, match="scene 'tshirt' sequence 'held_out_000': 60 frames with 30 settle"):
        scene_main([str(tmp_path / "settings.json"), str(tmp_path / "scene.h5"), "--sequence", "held_out_000"])
    assert not (tmp_path / "scene.h5").exists()


def test_high_res_pins_follow_their_parts_rigidly(pants):
    from pipeline.solvers.xpbd import subdivided_pins
    from geometry.loop_subdivision import loop_subdivide
    _, a, _ = pants
    S, _ = loop_subdivide(a["rest/vertices"], a["rest/faces"].astype(np.int64), 2)
    high_rest = S @ a["rest/vertices"]
    pins, part = subdivided_pins(S, a["pins/ids"].astype(np.int64), a["pins/part"].astype(np.int64))
    assert len(pins) > len(a["pins/ids"]) and np.array_equal(pins[:len(a["pins/ids"])], np.sort(a["pins/ids"]))
    targets = apply_rigid(a["pins/transforms"][:, part], high_rest[pins])
    assert np.abs(targets[0] - high_rest[pins]).max() < 1e-9     # frame 0 is the rest pose
    # in the torso frame the waist band does not move at all
    local = apply_rigid_inverse(a["torso_transforms"][:, None], targets)
    assert np.abs(local - local[0]).max() < 1e-9


@pytest.mark.parametrize("scene", ["tshirt", "skirt", "dress", "cape"])
def test_every_garment_scene_builds_and_simulates(scene, tmp_path):
    """The first frames of each shipped garment scene (CPU profile) with its physics switches: finite, pins on
    their targets, and the cloth outside the moving body up to a small tolerance."""
    from pipeline.solvers.xpbd import solver_settings
    from scenes.capsules import capsule_signed_distance
    from sim.xpbd import ClothModel, ClothSolver, FrameInputs
    settings = resolve_scene(CONFIG, scene, "cpu")
    a = scene_datasets(settings, tmp_path / "scene.h5")
    capsules = np.stack([a["capsules/a"], a["capsules/b"]], axis=2).astype(np.float64)
    radii = np.stack([a["capsules/radius_a"], a["capsules/radius_b"]], axis=1).astype(np.float64)
    model = ClothModel(a["rest/vertices"], a["rest/faces"].astype(np.int64), solver_settings(settings),
                       a["pins/ids"].astype(np.int64), capsule_radii=radii)
    solver = ClothSolver(model, "cpu", initial_inputs=FrameInputs(capsules=capsules[0]))
    start = settings["drivers"]["mannequin"]["settle_frames"]
    for f in range(1, start + 25):   # the settle period, then the first clip fading in
        solver.step(solver.state, FrameInputs(pin_targets=a["pins/targets"][f], capsules=capsules[f]))
        x = solver.state.read_positions()
    assert np.isfinite(x).all()
    np.testing.assert_allclose(x[a["pins/ids"]], a["pins/targets"][f], atol=1e-5)
    free = np.setdiff1d(np.arange(len(x)), a["pins/ids"])
    depth = capsule_signed_distance(x[free], capsules[f, :, 0], capsules[f, :, 1], radii[:, 0], radii[:, 1])
    assert depth.min() > -0.01


def test_readers_hand_the_stages_what_the_scene_holds(pants):
    """The typed readers of scene.h5 against the arrays written: what simulate, dataset and evaluate read."""
    settings, a, path = pants
    vertices, faces = read_rest_mesh(path)
    assert np.array_equal(vertices, a["rest/vertices"]) and faces.dtype == np.int64
    drive = read_scene_drive(path, body_collision=True)
    assert np.array_equal(drive.pins.ids, a["pins/ids"]) and drive.pins.targets.dtype == np.float64
    assert np.array_equal(drive.capsules[:, :, 1], a["capsules/b"]) and drive.capsule_radii.shape == (16, 2)
    assert drive.n_frames == settings["frames"]
    info = read_sequence(path)
    assert (info.name, info.role, info.n_frames) == ("train_000", "train", settings["frames"])
    assert info.clip_names[0] == "settle" and np.array_equal(info.clip, a["motion/clip"])
    assert info.settle_frames == settings["drivers"]["mannequin"]["settle_frames"] + 1   # the fade starts at rest
    assert np.array_equal(read_torso_transforms(path, settings["frames"]), a["torso_transforms"])
    skeleton, state = read_body(path)
    assert skeleton.height == 1.7 and np.array_equal(state.rotation, a["body/state/rotation"])
    body = read_mannequin_frames(path, 5)
    assert np.array_equal(body.per_frame["capsules/a"], a["capsules/a"][5:])
    assert np.array_equal(body.per_frame["torso_transforms"], a["torso_transforms"][5:])
    assert np.array_equal(body.constant["body/radius_b"], a["body/radius_b"]) and body.attrs["body"]["height"] == 1.7


def test_a_grid_scene_has_no_mannequin_to_read(tmp_path):
    settings = resolve_scene(CONFIG, "patch", "cpu")
    a = scene_datasets(settings, tmp_path / "scene.h5")
    assert read_body(tmp_path / "scene.h5") is None
    with pytest.raises(PipelineError, match="has no 'capsules'"):
        read_scene_drive(tmp_path / "scene.h5", body_collision=True)
    assert read_mannequin_frames(tmp_path / "scene.h5", 0) is None
    with pytest.raises(PipelineError, match="this scene has no torso"):
        read_torso_transforms(tmp_path / "scene.h5", len(a["pins/targets"]))
