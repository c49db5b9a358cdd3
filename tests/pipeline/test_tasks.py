"""The dataset stage's decoder tasks on a tiny pants scene with made-up runs: pose to cloth (the pose rows of
scene.h5 as input, linear blend skinning of the rest garment as predictor) and PCA details recovery (coefficients
of a PCA of the training frames as input, its reconstruction as predictor); in both, predictor + target is the
high-res run in the torso frame. Checked against references computed here: the run read back and moved into the
torso frame by hand, each body part's rigid motion for the vertices it alone drives, and the definition of a PCA
(orthonormal components, training residuals orthogonal to them)."""
import h5py
import numpy as np
import pytest

from geometry.loop_subdivision import loop_subdivide
from geometry.rigid import apply_rigid_inverse
from geometry.rotations import quat_conjugate, quat_multiply, quat_rotate
from pants_sequences import CONFIG, FRAMES, SEQUENCES, write_pants_sequences
from pipeline import dataset
from pipeline.core import cli
from pipeline.artifacts.dataset import load_dataset
from pipeline.core.h5 import atomic_h5, write_csr
from pipeline.artifacts.scene import read_body, read_skinning, read_torso_transforms
from pipeline.core.config import resolve_scene
from scenes.kinematics import rest_transforms
from scenes.registry import build_scene

K = 5


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Two training sequences and a held-out one of a tiny pants scene, their subdivision, and the pose and PCA
    datasets."""
    root = tmp_path_factory.mktemp("tasks")
    S, _ = write_pants_sequences(root)
    folders = [str(root / n) for n in SEQUENCES]
    cli.run(dataset.main, [str(root / "subdiv.h5"), str(root / "pose.h5"), *folders, "--frame", "torso",
                           "--task", "pose", "--quiet"])
    cli.run(dataset.main, [str(root / "subdiv.h5"), str(root / "pca.h5"), *folders, "--frame", "torso",
                           "--task", "pca", "--components", str(K), "--quiet"])
    return root, S


def high_in_torso_frame(root, f) -> np.ndarray:
    """Each frame's high-res position read back from its sequence's sim_high.h5, in its torso frame."""
    names = [n.decode() for n in f["sequences/names"][()]]
    sequence, frame = f["sequence"][()], f["sequence_frame"][()]
    out = np.empty((len(sequence), *f["target"].shape[1:]))
    for k, name in enumerate(names):
        rows = np.flatnonzero(sequence == k)
        with h5py.File(root / name / "sim_high.h5") as run:
            high = run["positions"][()].astype(np.float64)[frame[rows]]
        torso = read_torso_transforms(root / name / "scene.h5", FRAMES)[frame[rows]]
        out[rows] = apply_rigid_inverse(torso[:, None], high)
    return out


@pytest.mark.parametrize("task", ["pose", "pca"])
def test_predictor_plus_target_is_the_high_res_run_in_the_torso_frame(scene, task):
    root, _ = scene
    with h5py.File(root / f"{task}.h5") as f:
        assert f.attrs["task"] == task and "low" not in f
        np.testing.assert_allclose(f["predictor"][()] + f["target"][()], high_in_torso_frame(root, f), atol=2e-6)
    data = load_dataset(root / f"{task}.h5")
    assert data.task == task and data.predictor.shape == data.targets.shape
    assert data.inputs.shape == (len(data.targets), 208 if task == "pose" else K)


def test_pose_input_is_each_frames_pose_and_rigidly_driven_vertices_follow_their_part(scene):
    root, S = scene
    skeleton, _ = read_body(root / "train_000" / "scene.h5")
    influences, weights = read_skinning(root / "train_000" / "scene.h5")
    dense = np.zeros((len(weights), skeleton.n_parts))
    np.add.at(dense, (np.arange(len(weights))[:, None], influences), weights)
    high_weights = np.asarray(S @ dense)
    rest0_rotation, rest0_translation = rest_transforms(skeleton)
    with h5py.File(root / "pose.h5") as f:
        pose, predictor = f["pose"][()], f["predictor"][()]
        np.testing.assert_array_equal(f["input"][()], pose)
        rotation, translation = f["body/state/rotation"][()], f["body/state/translation"][()]
        torso, rest = f["torso_transforms"][()], f["rest_vertices"][()]
    assert pose.shape[1] == 13 * skeleton.n_parts == 208
    checked = 0
    for part in range(skeleton.n_parts):
        alone = np.flatnonzero(high_weights[:, part] > 1 - 1e-9)
        if len(alone) == 0:
            continue
        relative = quat_multiply(rotation[:, part], quat_conjugate(rest0_rotation[part]))      # (F, 4)
        world = quat_rotate(relative[:, None], rest[alone][None] - rest0_translation[part]) + translation[:, None, part]
        np.testing.assert_allclose(predictor[:, alone], apply_rigid_inverse(torso[:, None], world), atol=2e-5)
        checked += 1
    assert checked >= 2      # at least the two legs, on this coarse mesh


def test_pca_is_a_pca_of_the_training_frames(scene):
    root, _ = scene
    data = load_dataset(root / "pca.h5")
    basis = data.pca
    flat = basis.components.reshape(K, -1)
    np.testing.assert_allclose(flat @ flat.T, np.eye(K), atol=1e-10)
    truth = data.predictor.astype(np.float64) + data.targets
    np.testing.assert_allclose(data.inputs, (truth.reshape(len(truth), -1) - basis.mean.reshape(-1)) @ flat.T,
                               atol=1e-4, rtol=1e-4)
    train = truth[data.train].reshape(len(data.train), -1)
    centred = train - train.mean(axis=0)
    np.testing.assert_allclose(basis.mean.reshape(-1), train.mean(axis=0), atol=1e-9)
    residual = centred - (centred @ flat.T) @ flat
    # Principal directions: the residual of the training frames is orthogonal to every component, the captured
    # variance is the top of the spectrum, and each component's variance is its singular value squared.
    np.testing.assert_allclose(residual @ flat.T, 0.0, atol=1e-8)
    spectrum = np.linalg.eigvalsh(centred @ centred.T)[::-1]
    np.testing.assert_allclose(np.square(basis.singular_values), spectrum[:K], rtol=1e-6)
    assert basis.explained == pytest.approx(spectrum[:K].sum() / spectrum.sum(), rel=1e-6)
    assert basis.fitted_frames == len(data.train)


def test_pose_on_a_scene_without_a_mannequin_is_one_error(tmp_path, capsys):
    settings = resolve_scene(CONFIG, "patch", "cpu")
    scene = build_scene(settings, "train_000")
    S, high_faces = loop_subdivide(scene.rest.vertices, scene.rest.faces, 1)
    with atomic_h5(tmp_path / "subdiv.h5", "subdivide") as out:
        write_csr(out, "S", S)
        out["vertices"], out["faces"] = S @ scene.rest.vertices, high_faces.astype(np.int32)
    folder = tmp_path / "train_000"
    from pipeline.artifacts.scene import write_scene
    write_scene(folder / "scene.h5", scene, settings)
    low = np.repeat(scene.rest.vertices[None], scene.n_frames, axis=0)
    for level, positions, faces in (("low", low, scene.rest.faces), ("high", np.stack([S @ x for x in low]),
                                                                      high_faces)):
        with atomic_h5(folder / f"sim_{level}.h5", f"simulate_{level}", settings) as out:
            out["positions"], out["faces"] = positions.astype(np.float32), faces.astype(np.int32)
    with pytest.raises(SystemExit) as stop:
        cli.run(dataset.main, [str(tmp_path / "subdiv.h5"), str(tmp_path / "pose.h5"), str(folder), "--task", "pose"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {folder / 'scene.h5'}: task pose: this scene has no mannequin, so no pose input (a grid "
                   f"scene); pose to cloth needs a garment scene"]
    assert not (tmp_path / "pose.h5").exists()
