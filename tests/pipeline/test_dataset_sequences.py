"""The dataset stage gathering a garment scene's sequences: frames in order with their sequence ids, the settle
period kept once, the split (a random share of the training sequences' frames; every frame of the held-out ones),
the torso frame per sequence, each frame's mannequin under scene.h5's names, and clear errors."""
import hashlib

import h5py
import numpy as np
import pytest

from geometry.rigid import apply_rigid_inverse
from pants_sequences import FRAMES, SEQUENCES, SETTLE, write_pants_sequences
from pipeline import dataset
from pipeline.core import cli
from pipeline.artifacts.dataset import load_dataset
from pipeline.core.h5 import atomic_h5
from pipeline.artifacts.scene import read_body, read_torso_transforms


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Two training sequences and a held-out one of a tiny pants scene, their subdivision, and the dataset."""
    root = tmp_path_factory.mktemp("sequences")
    S, low = write_pants_sequences(root)
    cli.run(dataset.main, [str(root / "subdiv.h5"), str(root / "dataset.h5"), *(str(root / n) for n in SEQUENCES),
                           "--frame", "torso", "--quiet"])
    return root, S, low


def test_frames_follow_the_sequences_and_keep_the_settle_period_once(scene):
    root, _, _ = scene
    with h5py.File(root / "dataset.h5") as f:
        sequence, frame = f["sequence"][()], f["sequence_frame"][()]
        assert [n.decode() for n in f["sequences/names"][()]] == list(SEQUENCES)
        assert [r.decode() for r in f["sequences/role"][()]] == ["train", "train", "held_out"]
        assert f["sequences/clips"][2].decode() == "walk" and f["split"].attrs["held_out_clips"] == "walk"
        n_frames = f.attrs["n_frames"]
    clip = {}
    for name in SEQUENCES:
        with h5py.File(root / name / "scene.h5") as s:
            clip[name] = s["motion/clip"][()]
    first = {name: int(np.argmax(clip[name] > 0)) for name in SEQUENCES}   # frames before the first clip
    expected_frames = [np.arange(FRAMES), np.arange(first["train_001"], FRAMES),
                       np.arange(first["held_out_000"], FRAMES)]
    np.testing.assert_array_equal(frame, np.concatenate(expected_frames))
    np.testing.assert_array_equal(sequence, np.repeat([0, 1, 2], [len(f) for f in expected_frames]))
    assert n_frames == len(sequence) and first["train_001"] >= SETTLE


def test_split_shares_the_training_frames_and_holds_out_the_held_out_sequence(scene):
    root, _, _ = scene
    data = load_dataset(root / "dataset.h5")
    held = np.flatnonzero(data.sequence == 2)
    np.testing.assert_array_equal(data.held_out, held)
    seen = np.flatnonzero(data.sequence < 2)
    np.testing.assert_array_equal(np.sort(np.concatenate([data.train, data.test])), seen)
    assert len(data.test) == round(0.1 * len(seen))
    assert data.held_out_clips == "walk"


def test_inputs_are_each_sequences_runs_in_its_torso_frame(scene):
    root, S, low = scene
    data = load_dataset(root / "dataset.h5")
    with h5py.File(root / "dataset.h5") as f:
        frames = f["sequence_frame"][()]
    for k, name in enumerate(SEQUENCES):
        rows = np.flatnonzero(data.sequence == k)
        torso = read_torso_transforms(root / name / "scene.h5", FRAMES)[frames[rows]]
        local = apply_rigid_inverse(torso[:, None], low[name][frames[rows]].astype(np.float32).astype(np.float64))
        np.testing.assert_allclose(data.predictor[rows], np.stack([S @ x for x in local]), atol=1e-5)


def test_each_frame_carries_its_mannequin_under_the_scene_names(scene):
    root, _, _ = scene
    with h5py.File(root / "dataset.h5") as f:
        sequence, frames = f["sequence"][()], f["sequence_frame"][()]
        capsules, torso, pose = f["capsules/a"][()], f["torso_transforms"][()], f["pose"][()]
    for k, name in enumerate(SEQUENCES):
        rows = sequence == k
        with h5py.File(root / name / "scene.h5") as s:
            np.testing.assert_array_equal(capsules[rows], s["capsules/a"][()][frames[rows]])
            np.testing.assert_array_equal(torso[rows], s["torso_transforms"][()][frames[rows]])
            np.testing.assert_array_equal(pose[rows], s["pose"][()][frames[rows]])
    # what evaluate reads from a scene file reads the same from the dataset, frame by frame
    skeleton, state = read_body(root / "dataset.h5")
    assert skeleton.height == 1.7 and len(state.rotation) == len(sequence)
    assert read_torso_transforms(root / "dataset.h5", len(sequence)).shape == (len(sequence), 4, 4)


def test_each_frame_carries_gravity_and_the_capsules_in_the_torso_frame(scene):
    root, _, _ = scene
    data = load_dataset(root / "dataset.h5")
    with h5py.File(root / "dataset.h5") as f:
        world_a, torso = f["capsules/a"][()], f["torso_transforms"][()]
        assert f.attrs["frame_time"] == pytest.approx(1 / 60)
    gravity = np.array([0.0, -1.0, 0.0])                     # solver.gravity (0, -9.81, 0), as a unit vector
    for i in (0, len(torso) // 2, len(torso) - 1):
        rotation, translation = torso[i, :3, :3], torso[i, :3, 3]
        np.testing.assert_allclose(data.context.gravity[i], np.linalg.solve(rotation, gravity), atol=1e-6)
        np.testing.assert_allclose(data.context.capsule_a[i], np.linalg.solve(rotation, (world_a[i] - translation).T).T,
                                   atol=1e-5)
    assert data.context.capsule_b.shape == data.context.capsule_a.shape and np.all(data.context.radius_a > 0)
    # the previous frame restarts at each sequence's first kept frame
    starts = np.flatnonzero(np.r_[True, data.sequence[1:] != data.sequence[:-1]])
    np.testing.assert_array_equal(data.previous[starts], starts)
    np.testing.assert_array_equal(np.delete(data.previous, starts), np.delete(np.arange(len(data.previous)) - 1, starts))


def test_sequences_made_with_another_time_step_are_refused(scene, tmp_path, capsys):
    root, _, _ = scene
    other = tmp_path / "train_009"
    other.mkdir()
    (other / "scene.h5").write_bytes((root / "train_001" / "scene.h5").read_bytes())
    for level in ("low", "high"):
        with h5py.File(root / "train_001" / f"sim_{level}.h5") as f, \
                atomic_h5(other / f"sim_{level}.h5", f"simulate_{level}", {"solver": {"dt": 0.01, "gravity": [0, -9.81, 0]}}) as out:
            out["positions"], out["faces"] = f["positions"][()], f["faces"][()]
    with pytest.raises(SystemExit):
        run_dataset(root / "subdiv.h5", tmp_path / "d.h5", root / "train_000", other)
    assert f"{other / 'sim_low.h5'}: made with dt 0.01 s" in capsys.readouterr().err
    assert not (tmp_path / "d.h5").exists()


def run_dataset(*args) -> None:
    cli.run(dataset.main, [str(a) for a in args])


def test_gathering_errors_name_the_problem(scene, tmp_path, capsys):
    root, _, _ = scene
    cases = [
        ([root / "held_out_000"], "no training sequence"),
        ([root / "train_000", root / "train_000"], "sequence 'train_000' is given twice"),
        ([root / "train_000", tmp_path], f"{tmp_path / 'sim_low.h5'}: input file does not exist"),
    ]
    for folders, message in cases:
        with pytest.raises(SystemExit):
            run_dataset(root / "subdiv.h5", tmp_path / "d.h5", *folders)
        assert message in capsys.readouterr().err
    # a sequence folder without its scene cannot give the torso frame
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("sim_low.h5", "sim_high.h5"):
        (bare / name).write_bytes((root / "train_001" / name).read_bytes())
    with pytest.raises(SystemExit):
        run_dataset(root / "subdiv.h5", tmp_path / "d.h5", root / "train_000", bare, "--frame", "torso")
    assert f"{bare}: --frame torso needs the sequence's scene.h5" in capsys.readouterr().err
    # ... and with a mannequin in one sequence but not in the other, the world frame is refused too
    with pytest.raises(SystemExit):
        run_dataset(root / "subdiv.h5", tmp_path / "d.h5", root / "train_000", bare)
    assert "some sequences have a mannequin and some not" in capsys.readouterr().err
    assert not (tmp_path / "d.h5").exists()


def test_the_frames_are_a_per_frame_loops_bit_for_bit_and_any_threads_write_the_same_dataset(scene, tmp_path):
    """The stage's fast arithmetic (torso transforms one frame at a time, S x_low of many frames in one product,
    targets rounded straight into float32) gives the bits of the plain loop it replaced, and so the same frames
    digest; and --threads 3 writes the same dataset as the default, every array and attribute."""
    root, _, _ = scene
    data = load_dataset(root / "dataset.h5")
    S = data.subdivision
    with h5py.File(root / "dataset.h5") as f:
        frames, stored_digest = f["sequence_frame"][()], f.attrs["frames_digest"]
        digest = hashlib.sha256(b"".join(f[f"subdivision/{part}"][()].tobytes() for part in ("data", "indices",
                                                                                              "indptr")))
    for k, name in enumerate(SEQUENCES):
        rows = np.flatnonzero(data.sequence == k)
        torso = read_torso_transforms(root / name / "scene.h5", FRAMES)[frames[rows]]
        low, high = (apply_rigid_inverse(torso[:, None], positions(root / name / f"sim_{level}.h5")[frames[rows]])
                     for level in ("low", "high"))
        targets = (high - np.stack([S @ x for x in low])).astype(np.float32)
        assert np.array_equal(data.inputs[rows], low.astype(np.float32))
        assert np.array_equal(data.targets[rows], targets)
        digest.update(low.astype(np.float32).tobytes() + targets.tobytes())
    assert stored_digest == digest.hexdigest()
    run_dataset(root / "subdiv.h5", tmp_path / "threads.h5", *(root / n for n in SEQUENCES), "--frame", "torso",
                "--quiet", "--threads", "3")
    assert h5_contents(tmp_path / "threads.h5") == h5_contents(root / "dataset.h5")


def positions(path) -> np.ndarray:
    with h5py.File(path) as f:
        return f["positions"][()].astype(np.float64)


def h5_contents(path) -> dict:
    """Every object of an HDF5 file by name: its attributes and, for a dataset, its dtype, shape, chunks and bytes."""
    contents = {}
    with h5py.File(path) as f:
        def add(name, obj):
            attrs = {key: np.asarray(value).tobytes() for key, value in obj.attrs.items()}
            data = (obj.dtype, obj.shape, obj.chunks, obj[()].tobytes()) if isinstance(obj, h5py.Dataset) else None
            contents[name] = (attrs, data)
        add("/", f)
        f.visititems(add)
    return contents
