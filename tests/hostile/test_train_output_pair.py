"""Item 10 of issue 13, the train stage's two outputs: model.pt and train.h5 come as a pair or not at all. model.pt
is written first; if train.h5 then cannot be written (here a folder stands at its path, which no earlier check
looks at), the stage ends with one error line and takes model.pt away again, so Snakemake never sees a model
without its training log. The per-epoch checkpoint stays: rerun with a usable path, training resumes from it."""
from __future__ import annotations

from hostile import ARCH, assert_refused, files_in, run_in_process
from pipeline import train


def test_no_model_is_left_when_the_training_log_cannot_be_written(valid, tmp_path, capsys):
    (tmp_path / "train.h5").mkdir()
    before = files_in(tmp_path)
    run = run_in_process(train.main, valid / "dataset.h5", valid / "operators.h5", tmp_path / "model.pt",
                         tmp_path / "train.h5", *ARCH, "--epochs", "1", "--quiet", capsys=capsys)
    assert_refused(run, f"{tmp_path / 'train.h5'}: cannot write the output", "it is a folder")
    assert not (tmp_path / "model.pt").exists()
    assert files_in(tmp_path) - before == {"model.pt.ckpt"}, files_in(tmp_path) ^ before
