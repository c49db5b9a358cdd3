"""The evaluation of a motion library's scene by motion kind (issue 35 item 6): the held-out and test errors of the
network and of its predictor per manifest category and per subject, in eval.h5 and in the reports, checked against
the errors computed here from the predicted positions; the sequences dropped on the way listed with their reasons;
the test split named as drawn; none of it for a dataset without library windows; and a decoder task (PCA) the
same way."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from library_sheets import window, write_dropped_sequence, write_sheet_sequence
from pipeline import dataset, evaluate, operators, train
from pipeline.artifacts.dataset import load_dataset, read_dropped, read_library_windows
from pipeline.artifacts.evaluation import read_errors, read_errors_by_kind
from pipeline.core.errors import PipelineError
from stage_inputs import stage

FRAMES = 30
ROBOT_REASON = "scene.h5: 009/robot.bvh: no joint maps onto the mannequin's pelvis"
# name, role, (file, subject, category) of its window or None, amplitude of its waving
SEQUENCES = [("train_000", "train", None, 1.0),
             ("train_001-01_w00", "train", ("001/01.bvh", "1", "walk"), 1.3),
             ("train_002-01_w00", "train", ("002/01.bvh", "2", "run"), 0.7),
             ("held_out_000", "held_out", None, 1.2),
             ("held_out_003-01_w00", "held_out", ("003/01.bvh", "3", "walk"), 1.1),
             ("held_out_010-01_w00", "held_out", ("010/01.bvh", "10", ""), 0.9)]
CATEGORY = {"walk": "walk", "run": "run", "": "(no category)", None: "(no library window)"}
EVALUATE = ["--render-frames", 2, "--video-frames", 8, "--export-frames", 1, "--timing-frames", 1, "--quiet"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The sequences' folders (a dropped window among them), operators, a windows-split dataset and a network
    trained on it."""
    root = tmp_path_factory.mktemp("by_kind")
    folders = []
    for name, role, played, amplitude in SEQUENCES:
        described = None if played is None else window(*played, 0.0, FRAMES * 0.1)
        folders.append(write_sheet_sequence(root, name, role, described, FRAMES, amplitude))
    folders.insert(3, write_dropped_sequence(root, "train_009-robot_w00", ROBOT_REASON))
    stage(operators.main, root / "subdiv.h5", root / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    stage(dataset.main, root / "subdiv.h5", root / "dataset.h5", *folders, "--test-split", "windows",
          "--test-window", 0.5, "--guard", 0.2, "--test-fraction", 0.2, "--quiet")
    stage(train.main, root / "dataset.h5", root / "operators.h5", root / "model.pt", root / "train.h5", "--arch",
          "D8 D16 D D16", "--conv", "RC7", "--epochs", 2, "--quiet")
    return root, folders


@pytest.fixture(scope="module")
def evaluated(scene):
    """The network's evaluation: root/eval/ holds eval.h5, report.md and report.html."""
    root, _ = scene
    out = root / "eval"
    stage(evaluate.main, root / "dataset.h5", root / "operators.h5", root / "model.pt", out / "eval.h5",
          out / "report.md", "--html", out / "report.html", *EVALUATE)
    return root, out


def test_the_dataset_lists_each_sequences_window_and_the_dropped_one(scene):
    root, _ = scene
    windows = read_library_windows(root / "dataset.h5")
    assert windows.category == ("", "walk", "run", "", "walk", "")
    assert windows.subject == ("", "1", "2", "", "3", "10") and windows.file[1] == "001/01.bvh"
    np.testing.assert_array_equal(windows.span[:, 1], [-1, 3.0, 3.0, -1, 3.0, 3.0])
    assert read_dropped(root / "dataset.h5") == (("train_009-robot_w00", f"scene.h5: {ROBOT_REASON}"),)


def test_errors_by_category_and_subject_are_those_of_their_frames(evaluated):
    root, out = evaluated
    data = load_dataset(root / "dataset.h5")
    with h5py.File(out / "eval.h5") as f:
        predicted = f["predicted"][()].astype(np.float64)
    truth = (data.predictor + data.targets).astype(np.float64)
    by_kind = read_errors_by_kind(out / "eval.h5")
    labels_of = {"category": [CATEGORY[None if p is None else p[2]] for _, _, p, _ in SEQUENCES],
                 "subject": ["(no library window)" if p is None else p[1] for _, _, p, _ in SEQUENCES]}
    assert by_kind["subject"].labels == ("1", "2", "3", "10", "(no library window)")
    for grouping, groups in by_kind.items():
        assert set(groups.frames) == {"test", "held_out"}
        per_frame_label = np.array(labels_of[grouping])[data.sequence]
        for split, ids in (("test", data.test), ("held_out", data.held_out)):
            for k, label in enumerate(groups.labels):
                frames = ids[per_frame_label[ids] == label]
                assert groups.frames[split][k] == len(frames)
                for who, positions in (("network", predicted), ("predictor", data.predictor)):
                    l1, l2 = groups.errors[split][who]["l1"][k], groups.errors[split][who]["l2"][k]
                    if not len(frames):
                        assert np.isnan(l1) and np.isnan(l2)
                        continue
                    difference = positions[frames] - truth[frames]
                    assert l1 == pytest.approx(np.abs(difference).mean(), rel=1e-4)
                    assert l2 == pytest.approx(np.sqrt((difference ** 2).sum(-1).mean()), rel=1e-4)
    # the groups of a split make up the split: their frame-weighted errors are the split's, computed by torch
    errors = read_errors(out / "eval.h5")
    for split in ("test", "held_out"):
        groups = by_kind["category"]
        weights = groups.frames[split] / groups.frames[split].sum()
        counted = groups.frames[split] > 0
        for who in ("network", "predictor"):
            l1 = np.sum(weights[counted] * groups.errors[split][who]["l1"][counted])
            l2 = np.sqrt(np.sum(weights[counted] * groups.errors[split][who]["l2"][counted] ** 2))
            assert l1 == pytest.approx(errors[who][split]["l1"], rel=1e-4)
            assert l2 == pytest.approx(errors[who][split]["l2"], rel=1e-4)


def test_the_report_shows_a_table_per_grouping_the_dropped_sequences_and_how_the_test_was_drawn(evaluated):
    root, out = evaluated
    report, page = (out / "report.md").read_text(), (out / "report.html").read_text()
    by_kind = read_errors_by_kind(out / "eval.h5")
    data = load_dataset(root / "dataset.h5")
    assert "## Errors by motion kind" in report and "<h2>Errors by motion kind</h2>" in page
    for grouping, groups in by_kind.items():
        assert f"| {grouping} | split | frames | network L1 | predictor L1 | L1 gain |" in report
        for split, name in (("held_out", "held-out"), ("test", "test")):
            for k in np.flatnonzero(groups.frames[split]):
                network = groups.errors[split]["network"]["l1"][k] * 1e3
                predictor = groups.errors[split]["predictor"]["l1"][k] * 1e3
                row = (f"| {groups.labels[k]} | {name} | {groups.frames[split][k]} | {network:.3f} | "
                       f"{predictor:.3f} | {predictor / network:.2f}x |")
                assert row in report
            for k in np.flatnonzero(groups.frames[split] == 0):   # a group without frames of a split: no row
                assert f"| {groups.labels[k]} | {name} |" not in report
    assert "## Dropped sequences" in report
    assert f"| train_009-robot_w00 | scene.h5: {ROBOT_REASON} |" in report and "train_009-robot_w00" in page
    assert "Test: contiguous blocks of up to 0.5 s of the trained sequences, no frame trained on within 0.2 s" in report
    assert f"{len(data.guard)} guard (in no split)" in report and len(data.guard) > 0


def test_a_dataset_without_library_windows_gets_no_tables_by_kind(scene, tmp_path):
    root, folders = scene
    plain = tmp_path / "train_000"
    plain.mkdir()
    for name in ("sim_low.h5", "sim_high.h5"):      # a folder without scene.h5: a sequence of no library
        (plain / name).write_bytes((folders[0] / name).read_bytes())
    stage(dataset.main, root / "subdiv.h5", tmp_path / "dataset.h5", plain, "--quiet")
    stage(evaluate.main, tmp_path / "dataset.h5", root / "operators.h5", root / "model.pt", tmp_path / "eval.h5",
          tmp_path / "report.md", *EVALUATE)
    assert read_library_windows(tmp_path / "dataset.h5") is None and read_dropped(tmp_path / "dataset.h5") == ()
    assert read_errors_by_kind(tmp_path / "eval.h5") == {}
    with h5py.File(tmp_path / "eval.h5") as f:
        assert "by_kind" not in f
    report = (tmp_path / "report.md").read_text()
    assert "Errors by motion kind" not in report and "Dropped sequences" not in report
    assert "Test: a random share of the frames of the trained sequences" in report


def test_a_decoder_task_is_evaluated_by_motion_kind_too(scene, tmp_path):
    root, folders = scene
    stage(dataset.main, root / "subdiv.h5", tmp_path / "pca.h5", *folders, "--task", "pca", "--components", 3,
          "--test-split", "windows", "--test-window", 0.5, "--guard", 0.2, "--test-fraction", 0.2, "--quiet")
    stage(train.main, tmp_path / "pca.h5", root / "operators.h5", tmp_path / "model.pt", tmp_path / "train.h5",
          "--arch", "U8 U3", "--conv", "RC7", "--epochs", 1, "--quiet")
    stage(evaluate.main, tmp_path / "pca.h5", root / "operators.h5", tmp_path / "model.pt", tmp_path / "eval.h5",
          tmp_path / "report.md", *EVALUATE)
    by_kind = read_errors_by_kind(tmp_path / "eval.h5")
    data = load_dataset(tmp_path / "pca.h5")
    walk = by_kind["category"].labels.index("walk")
    held_walk = data.held_out[data.sequence[data.held_out] == 4]            # held_out_003-01_w00
    difference = data.targets[held_walk].astype(np.float64)                 # the predictor's error: -target
    assert by_kind["category"].errors["held_out"]["predictor"]["l1"][walk] == \
           pytest.approx(np.abs(difference).mean(), rel=1e-4)
    report = (tmp_path / "report.md").read_text()
    assert "of the network and of PCA reconstruction alone (the predictor)" in report
    assert "| train_009-robot_w00 |" in report


def test_damaged_tables_by_kind_are_one_error(evaluated, tmp_path):
    _, out = evaluated
    damaged = tmp_path / "eval.h5"
    damaged.write_bytes((out / "eval.h5").read_bytes())
    with h5py.File(damaged, "r+") as f:
        frames = f["by_kind/subject/test/frames"]
        frames[0] = 3 if frames[0] == 0 else frames[0]
        f["by_kind/subject/test/network_l1"][0] = np.nan        # a counted group without a number
    with pytest.raises(PipelineError, match="'by_kind' must hold, per grouping category, subject"):
        read_errors_by_kind(damaged)


@pytest.mark.parametrize("name, data, message", [
    ("sequences/subject", np.array([b"1", b"2"]), "'sequences/subject' must be a list of texts, one per entry"),
    ("sequences/category", np.array([b"\xff"] * 6), "'sequences/category' holds text that is not UTF-8"),
    ("sequences/library_span", np.zeros((6, 3)), r"'sequences/library_span' \(6, 3\) must be \(6, 2\)"),
    ("dropped/reasons", np.array([b"a", b"b"]), "'dropped/reasons' must be a list of texts, one per entry"),
])
def test_damaged_lists_of_windows_and_dropped_sequences_are_one_error(scene, tmp_path, name, data, message):
    root, _ = scene
    damaged = tmp_path / "dataset.h5"
    damaged.write_bytes((root / "dataset.h5").read_bytes())
    with h5py.File(damaged, "r+") as f:
        del f[name]
        f[name] = data
    with pytest.raises(PipelineError, match=message):
        read_dropped(damaged) if name.startswith("dropped") else read_library_windows(damaged)
