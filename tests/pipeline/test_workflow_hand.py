"""`results/hand/` end to end at a tiny size (a 12 mm hand: ~1,500 skin vertices, ~2,900 tets; two training
sequences and the held-out fist of 24 frames; a small decoder): the mesh, the batched FEM runs, the dataset, the
operators on the skin, training and the report. Checked against independent computations: the dataset's
predictor is linear blend skinning recomputed here from the angles, predictor + target is the FEM's skin, the
rest frame is the rest skin, the held-out split is exactly the fist's frames; and the network beats linear blend
skinning on the test frames."""
import h5py
import numpy as np
import pytest
import yaml

from pipeline import hand_dataset, hand_simulate, workflow_plan
from pipeline.artifacts.hand import read_hand, read_hand_run
from pipeline.core.errors import PipelineError
from scenes.hand_motion import fist_trajectory
from scenes.hand_skeleton import ANGLE_LIMITS, hand_transforms
from hand_files import FRAMES, SEQUENCES, hand_config
from workflow_runs import build, snakemake, tail


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("hand")
    run = build(workdir, "results/hand/", "--configfile", str(hand_config(workdir)))
    assert run.returncode == 0, tail(run)
    return workdir / "results" / "hand"


def test_the_hand_scene_makes_every_product_and_its_report_shows_the_skin(hand):
    for name in ("hand.h5", "operators.h5", "dataset.h5", "model.pt", "train.h5", "eval.h5", "report.md",
                 "report.html"):
        assert (hand / name).is_file(), name
    for name in SEQUENCES:
        assert (hand / "sequences" / name / "fem.h5").is_file()
    assert list((hand / "renders").glob("frame_*.png"))
    report = (hand / "report.md").read_text()
    assert "18 scalars per frame" in report and "linear blend skinning | FEM ground truth | network output" in report
    assert "The FEM it replaces took a median" in report and "x faster** (Table 4's speedup column)" in report


def test_the_fem_runs_start_at_rest_play_their_angles_and_converge(hand):
    skin = read_hand(hand / "hand.h5")
    for name in SEQUENCES:
        run = read_hand_run(hand / "sequences" / name / "fem.h5", len(skin.skin_vertices))
        assert run.skin.shape == (FRAMES, len(skin.skin_vertices), 3)
        np.testing.assert_allclose(run.skin[0], skin.skin_vertices, atol=1e-6)    # the embedding at rest
        assert np.all(run.angles >= ANGLE_LIMITS[:, 0] - 1e-9) and np.all(run.angles <= ANGLE_LIMITS[:, 1] + 1e-9)
        assert run.converged.mean() > 0.9 and np.all(run.solve_ms[1:] > 0)
    fist = read_hand_run(hand / "sequences" / "held_out_000" / "fem.h5", len(skin.skin_vertices))
    np.testing.assert_allclose(fist.angles, fist_trajectory(FRAMES))
    train = [read_hand_run(hand / "sequences" / n / "fem.h5", len(skin.skin_vertices)) for n in SEQUENCES[:2]]
    assert not np.allclose(train[0].angles, train[1].angles)          # each training sequence its own seed
    assert train[0].angles[1:].std() > 0.05
    assert [r.worlds for r in train] == [2, 2] and fist.worlds == 1     # a shard is one batch of worlds


def test_the_dataset_is_fem_minus_linear_blend_skinning_with_the_fist_held_out(hand):
    skin = read_hand(hand / "hand.h5")
    runs = [read_hand_run(hand / "sequences" / n / "fem.h5", len(skin.skin_vertices)) for n in SEQUENCES]
    with h5py.File(hand / "dataset.h5") as f:
        assert f.attrs["task"] == "hand" and f["input"].shape == (3 * FRAMES, 18)
        inputs, predictor, target = f["input"][()], f["predictor"][()], f["target"][()]
        held_out, train, test = f["split/held_out"][()], f["split/train"][()], f["split/test"][()]
        assert f.attrs["fem_ms_per_frame"] > 0 and f.attrs["fem_worlds"] == 2
    np.testing.assert_allclose(inputs, np.concatenate([run.angles for run in runs]), atol=1e-6)
    np.testing.assert_allclose(predictor + target, np.concatenate([run.skin for run in runs]), atol=1e-5)
    # Linear blend skinning recomputed here, bone by bone, from the angles: sum_k w_k (R_k r_k^-1) x.
    angles = runs[0].angles[FRAMES // 2]
    rotation, translation = hand_transforms(skin.skeleton, angles)
    rest_rotation, rest_translation = hand_transforms(skin.skeleton, np.zeros(18))
    expected = np.zeros_like(skin.skin_vertices)
    for k in range(4):
        part = skin.skin_influences[:, k]
        local = _rotate(rest_rotation[part], skin.skin_vertices - rest_translation[part], inverse=True)
        expected += skin.skin_weights[:, k:k + 1] * (_rotate(rotation[part], local) + translation[part])
    np.testing.assert_allclose(predictor[FRAMES // 2], expected, atol=1e-5)
    np.testing.assert_array_equal(held_out, np.arange(2 * FRAMES, 3 * FRAMES))
    assert len(np.intersect1d(train, test)) == 0 and len(train) + len(test) == 2 * FRAMES


def _rotate(q, v, inverse=False):
    """Rotate vectors v (N, 3) by unit quaternions q (N, 4) xyzw (or by their inverses)."""
    u, w = (-q[:, :3] if inverse else q[:, :3]), q[:, 3:]
    return v + 2 * np.cross(u, np.cross(u, v) + w * v)


def test_the_network_beats_linear_blend_skinning_on_the_test_frames(hand):
    with h5py.File(hand / "eval.h5") as f:
        network, predictor = (f[f"errors/{who}/test/l1"][()] for who in ("network", "predictor"))
        held = f["errors/network/held_out/l1"][()]
        assert f.attrs["predictor"] == "linear blend skinning" and "skinning alone" in f["errors"].attrs["meaning"]
    assert network < predictor and np.isfinite(held)


def test_the_plan_states_what_the_fem_runs_weigh(hand, capsys, monkeypatch):
    workdir = hand.parents[1]
    monkeypatch.chdir(workdir)
    workflow_plan.plan(yaml.safe_load((workdir / "hand.yaml").read_text()), True, ["results/hand/"])
    disk = [line for line in capsys.readouterr().err.splitlines() if line.startswith("disk:")]
    runs = 0
    for name in SEQUENCES:
        with h5py.File(hand / "sequences" / name / "fem.h5") as f:
            runs += f["skin"].nbytes
            vertices = f["skin"].shape[1]
    assert disk == [f"disk: hand, {vertices:,} skin vertices: {workflow_plan._size(runs)} of FEM runs "
                    f"({workflow_plan._size(12 * vertices)} a frame), at most "
                    f"{workflow_plan._size(2 * runs + 3 * FRAMES * workflow_plan.DATASET_FRAME_EXTRA)} of dataset"]


def test_a_damaged_hand_file_is_one_error(hand, tmp_path):
    damaged = tmp_path / "hand.h5"
    damaged.write_bytes((hand / "hand.h5").read_bytes())
    with h5py.File(damaged, "r+") as f:
        tets = f["volume/tets"][()]
        tets[0, 0] = len(f["volume/nodes"])        # a node that is not there
        f["volume/tets"][...] = tets
    with pytest.raises(PipelineError, match="volume/tets"):
        read_hand(damaged)


def test_a_run_planned_without_its_skin_is_checked_all_the_same(hand, tmp_path):
    """The dataset stage plans from the runs without their skins (one is read at a time as it is written): the
    skin stays on disk, everything else is read, and a skin of the wrong shape is refused all the same."""
    path = hand / "sequences" / SEQUENCES[0] / "fem.h5"
    n_skin = len(read_hand(hand / "hand.h5").skin_vertices)
    whole, planned = read_hand_run(path, n_skin), read_hand_run(path, n_skin, skin=False)
    assert planned.skin is None and whole.skin.shape == (FRAMES, n_skin, 3)
    assert np.array_equal(planned.angles, whole.angles) and np.array_equal(planned.solve_ms, whole.solve_ms)
    short = tmp_path / "fem.h5"
    short.write_bytes(path.read_bytes())
    with h5py.File(short, "r+") as f:
        skin = f["skin"][:, :-1]
        del f["skin"]
        f["skin"] = skin
    with pytest.raises(PipelineError, match=r"'skin' \(\d+, \d+, 3\) must be"):
        read_hand_run(short, n_skin, skin=False)


def test_a_hand_scene_must_be_moved_by_the_fem(tmp_path):
    config = hand_config(tmp_path, solver={"kind": "xpbd"})
    run = snakemake(tmp_path, "results/hand/", "-n", "--configfile", str(config))
    assert run.returncode != 0 and "solver.kind must be 'fem' exactly when mesh.generator is 'hand'" in run.stderr


def test_the_hand_stages_refuse_sequences_they_cannot_make_or_order(hand, tmp_path):
    sequences = [str(hand / "sequences" / name) for name in ("held_out_000", "train_000")]
    with pytest.raises(PipelineError, match="the training ones first"):
        hand_dataset.main([str(hand / "hand.h5"), str(tmp_path / "dataset.h5"), *sequences])
    with pytest.raises(PipelineError, match="no held-out hand motion for sequence 'held_out_001'"):
        hand_simulate.main([str(hand / "simulation.json"), str(hand / "hand.h5"), "held_out_001",
                            str(tmp_path / "fem.h5")])
    assert not list(tmp_path.iterdir())            # nothing half-written
