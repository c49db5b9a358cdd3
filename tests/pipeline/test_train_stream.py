"""Issue 35, item 4, at the stages: `train` streams a dataset that does not fit --device-cache-gb from disk and
trains what it trains with the dataset resident, bit for bit; --train-on train,held_out (the oracle) is recorded
in model.pt and train.h5 and the evaluation's report says it plainly; model.pt lists the sequences trained on;
a dataset.h5 of the old layout (S x_low stored as `input`) is refused with one error line; --train-frames trains
on whole sequences within a budget (the study's curve against training frames)."""
from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import torch

from pipeline import dataset, evaluate, operators, train
from pipeline.core.h5 import config_of
from stage_inputs import stage, write_sequence_scene, write_waving_sheet

ARCH = ["--arch", "D8 D16 D D16", "--conv", "RC7"]
FRAMES = 30
# A share of the frames in blocks, shuffled in a buffer smaller than an epoch: the loader reads several windows.
SAMPLING = ["--sample-share", "0.5", "--sample-block", "4", "--sample-buffer", "6", "--batch-size", "3"]


@pytest.fixture(scope="module")
def sheets(tmp_path_factory) -> Path:
    """A training sequence and a held-out one of the waving sheet (the held-out one turned about y), their
    dataset and operators."""
    folder = tmp_path_factory.mktemp("stream")
    turned = np.array([[0.8, 0.0, 0.6], [0.0, 1.0, 0.0], [-0.6, 0.0, 0.8]])
    for name, role, transform in (("train_000", "train", lambda x, f: x), ("held_out_000", "held_out",
                                                                         lambda x, f: x @ turned.T)):
        (folder / name).mkdir()
        write_waving_sheet(folder, n_frames=FRAMES, runs_folder=name, transform=transform)
        write_sequence_scene(folder / name, name, role, FRAMES)
    stage(operators.main, folder / "subdiv.h5", folder / "operators.h5", "--conv", "RC7", "--levels", "4", "--quiet")
    stage(dataset.main, folder / "subdiv.h5", folder / "dataset.h5", folder / "train_000", folder / "held_out_000",
          "--quiet")
    return folder


def _train(folder: Path, out: str, *flags) -> dict:
    """Train for two epochs into folder/out/; model.pt's state."""
    (folder / out).mkdir()
    stage(train.main, folder / "dataset.h5", folder / "operators.h5", folder / out / "model.pt",
          folder / out / "train.h5", *ARCH, *SAMPLING, "--epochs", "2", "--quiet", *flags)
    return torch.load(folder / out / "model.pt", weights_only=True)


def test_a_streamed_training_is_the_resident_one_bit_for_bit(sheets):
    resident = _train(sheets, "resident")
    streamed = _train(sheets, "streamed", "--device-cache-gb", "0")
    assert not resident["training"]["streamed"] and streamed["training"]["streamed"]
    for name, value in resident["state_dict"].items():
        assert torch.equal(streamed["state_dict"][name], value), name
    with h5py.File(sheets / "resident" / "train.h5") as a, h5py.File(sheets / "streamed" / "train.h5") as b:
        assert np.array_equal(a["batch/total"][()], b["batch/total"][()])
        # Per epoch 4 of the 27 training frames' 7 blocks (the last one 3 frames): 16 or 15 frames, 6 or 5 steps.
        assert 2 * 5 <= len(a["batch/total"]) <= 2 * 6
    assert resident["training"]["sequences"] == {"names": ["train_000"]}
    assert resident["training"]["train_on"] == ["train"]


def test_the_oracle_is_recorded_and_the_report_says_the_held_out_frames_were_trained_on(sheets):
    state = _train(sheets, "oracle", "--train-on", "train,held_out", "--train-frames", "1")  # one sequence at least
    assert state["training"]["train_on"] == ["train", "held_out"]
    assert state["training"]["sequences"]["names"] == ["train_000", "held_out_000"]
    with h5py.File(sheets / "oracle" / "train.h5") as f:
        assert config_of(f)["train_on"] == ["train", "held_out"]
    out = sheets / "oracle"
    stage(evaluate.main, sheets / "dataset.h5", sheets / "operators.h5", out / "model.pt", out / "eval.h5",
          out / "report.md", "--render-frames", "0", "--video-frames", "0", "--export-frames", "1",
          "--timing-frames", "1", "--quiet")
    report = (out / "report.md").read_text()
    assert "The held-out frames were trained on" in report and "train and held-out: an oracle" in report
    assert "| sequences trained on | 2 |" in report
    assert f"| frames trained on | {state['training']['train_frames']} |" in report


def test_a_dataset_of_the_old_layout_is_refused_with_one_error_line(sheets, tmp_path, capsys):
    old = tmp_path / "dataset.h5"
    shutil.copy(sheets / "dataset.h5", old)
    with h5py.File(old, "r+") as f:       # as pipeline.dataset wrote it before: S x_low stored, no format attr
        del f.attrs["format"]
        f["input"] = np.zeros((FRAMES, *f["target"].shape[1:]), np.float32)
    with pytest.raises(SystemExit) as exit_info:
        stage(train.main, old, sheets / "operators.h5", tmp_path / "model.pt", tmp_path / "train.h5", *ARCH,
              "--epochs", "1", "--quiet")
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(lines) == 1
    assert lines[0].startswith(f"error: {old}: a dataset of an older pipeline.dataset") and "make it again" in lines[0]
    assert not (tmp_path / "model.pt").exists()


def test_train_frames_keeps_whole_sequences_within_the_budget_and_every_held_out_frame():
    # Sequences 0-3 of 5, 3, 4, 2 training frames, sequence 4 held out (3 frames); ids as an oracle trains on.
    sequence = np.repeat([0, 1, 2, 3, 4], [5, 3, 4, 2, 3])
    data = SimpleNamespace(sequence=sequence, held_out=np.arange(14, 17))
    ids = np.arange(17)
    for budget in (1, 2, 6, 9, 14, 100):
        kept = train.sequences_within(data, ids, budget, seed=3)
        trained = np.setdiff1d(kept, data.held_out)
        sizes = np.bincount(sequence[trained], minlength=4)[:4]
        assert set(np.arange(14, 17)) <= set(kept)                                   # the oracle's frames stay
        assert all(sizes[k] in (0, [5, 3, 4, 2][k]) for k in range(4))                # whole sequences only
        assert sizes.sum() <= budget or np.count_nonzero(sizes) == 1                # within it, or the first one
        if budget >= 14:
            assert sizes.sum() == 14
    assert np.array_equal(train.sequences_within(data, ids, 7, seed=3), train.sequences_within(data, ids, 7, seed=3))


@pytest.mark.parametrize("every, kept, epochs, share, block", [(112_000, 1_000, 6, 0.1, 1), (112_000, 10_000, 6, 0.1, 1),
                                                              (112_000, 60_000, 6, 0.1, 1), (900, 300, 8, 1.0, 1),
                                                              (5_000, 700, 3, 0.25, 4)])
def test_fewer_frames_take_the_steps_of_every_frame_share_first(every, kept, epochs, share, block):
    sampling = train.SampleSettings(share, block, 4096)
    new_epochs, new_sampling = train.same_steps(every, kept, epochs, sampling)
    full = epochs * train.Sampler(every, sampling).frames_per_epoch
    visited = new_epochs * train.Sampler(kept, new_sampling).frames_per_epoch
    assert abs(visited - full) <= train.Sampler(kept, new_sampling).frames_per_epoch / 2   # within half an epoch
    assert new_sampling.share == min(1.0, share * every / kept) and new_sampling.block == block
    assert new_epochs >= epochs or new_sampling.share < 1.0


def test_a_network_fed_its_previous_output_trains_evaluates_by_rollout_and_is_not_streamed(sheets, tmp_path, capsys):
    state = _train(sheets, "autoregressive", "--inputs", "position,previous_output")
    assert list(state["features"]["inputs"]) == ["position", "previous_output"]
    out = sheets / "autoregressive"
    stage(evaluate.main, sheets / "dataset.h5", sheets / "operators.h5", out / "model.pt", out / "eval.h5",
          out / "report.md", "--render-frames", "0", "--video-frames", "0", "--export-frames", "0",
          "--timing-frames", "1", "--quiet")
    with h5py.File(out / "eval.h5") as f:
        held_out = f["errors/network/held_out/l1"][()]
        per_frame = f["per_frame/network_l1"][()]
    assert np.isfinite(held_out) and np.isfinite(per_frame).all()
    with pytest.raises(SystemExit) as exit_info:
        stage(train.main, sheets / "dataset.h5", sheets / "operators.h5", tmp_path / "model.pt", tmp_path / "t.h5",
              *ARCH, "--inputs", "position,previous_output", "--device-cache-gb", "0", "--epochs", "1", "--quiet")
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(lines) == 1 and "previous output" in lines[0]
    assert not (tmp_path / "model.pt").exists()
    # Rolled out over every frame at once: nor is it evaluated on a streamed dataset.
    with pytest.raises(SystemExit) as exit_info:
        stage(evaluate.main, sheets / "dataset.h5", sheets / "operators.h5", out / "model.pt", tmp_path / "eval.h5",
              tmp_path / "report.md", "--device-cache-gb", "0", "--timing-frames", "1", "--quiet")
    lines = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(lines) == 1
    assert "previous output" in lines[0] and "--device-cache-gb room for" in lines[0]
    assert not (tmp_path / "eval.h5").exists() and not (tmp_path / "export").exists()
