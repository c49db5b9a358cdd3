"""Items 2 and 4 of issue 13: a checkpoint is read without unpickling code, and its path may not alias any other
input or output of the train stage."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
import torch

from hostile import ARCH, REPO, assert_refused, files_in, run_in_process, run_stage
from model.training import CHECKPOINT_FORMAT
from pipeline import train
from pipeline.core.config import load_config, resolve_scene, write_settings


class _Payload:
    """Unpickling this calls open(marker, 'w'): a stand-in for whatever code a crafted pickle could run."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def _plant(path: Path, marker: Path) -> None:
    torch.save({"format": CHECKPOINT_FORMAT, "history": _Payload(marker)}, path)


def test_checkpoint_that_would_run_code_is_refused_and_never_run(valid, tmp_path):
    probe, ran = tmp_path / "probe.ckpt", tmp_path / "ran"
    _plant(probe, ran)
    torch.load(probe, weights_only=False)["history"].close()     # the payload works where pickles are trusted
    assert ran.exists()
    out, marker = tmp_path / "out", tmp_path / "pwned"
    out.mkdir()
    _plant(out / "model.pt.ckpt", marker)
    before = files_in(out)
    run = run_stage("train", valid / "dataset.h5", valid / "operators.h5", out / "model.pt", out / "train.h5", *ARCH,
                    "--epochs", "1", "--quiet")
    assert_refused(run, str(out / "model.pt.ckpt"), "not a training checkpoint", folder=out, before=before)
    assert not marker.exists()


def test_a_file_that_is_no_checkpoint_is_refused_not_overwritten(valid, tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("someone's notes")
    before = files_in(tmp_path)
    run = run_in_process(train.main, valid / "dataset.h5", valid / "operators.h5", tmp_path / "model.pt",
                         tmp_path / "train.h5", *ARCH, "--epochs", "1", "--checkpoint", notes, "--quiet",
                         capsys=capsys)
    assert_refused(run, str(notes), "not a training checkpoint", folder=tmp_path, before=before)
    assert notes.read_text() == "someone's notes"


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir() if p.is_file()}


# Each case: (checkpoint, model, log) as paths relative to a folder holding dataset.h5, operators.h5 and
# settings.json; the roles the error must name.
ALIASES = {
    "checkpoint is the dataset": (("dataset.h5", "model.pt", "train.h5"), ("DATASET", "--checkpoint")),
    "checkpoint is the operators": (("operators.h5", "model.pt", "train.h5"), ("OPERATORS", "--checkpoint")),
    "checkpoint is the model": (("model.pt", "model.pt", "train.h5"), ("MODEL", "--checkpoint")),
    "checkpoint is the log": (("train.h5", "model.pt", "train.h5"), ("LOG", "--checkpoint")),
    "checkpoint is the settings": (("settings.json", "model.pt", "train.h5"), ("--settings", "--checkpoint")),
    "checkpoint is the dataset spelled otherwise": (("sub/../dataset.h5", "model.pt", "train.h5"),
                                                    ("DATASET", "--checkpoint")),
    "checkpoint is a link to the dataset": (("link.h5", "model.pt", "train.h5"), ("DATASET", "--checkpoint")),
    "model is the log": (("model.pt.ckpt", "train.h5", "train.h5"), ("MODEL", "LOG")),
}


@pytest.mark.parametrize("case", ALIASES)
def test_checkpoint_aliasing_another_path_is_refused_before_anything_is_written(valid, tmp_path, capsys, case):
    (checkpoint, model, log), roles = ALIASES[case]
    for name in ("dataset.h5", "operators.h5"):
        shutil.copy(valid / name, tmp_path / name)
    settings = resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch")
    write_settings(settings, tmp_path / "settings.json")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.h5").symlink_to(tmp_path / "dataset.h5")
    before, digest = files_in(tmp_path), _digest(tmp_path)
    run = run_in_process(train.main, tmp_path / "dataset.h5", tmp_path / "operators.h5", tmp_path / model,
                         tmp_path / log, "--settings", tmp_path / "settings.json", *ARCH, "--epochs", "1",
                         "--checkpoint", tmp_path / checkpoint, "--quiet", capsys=capsys)
    assert_refused(run, *roles, "same file", folder=tmp_path, before=before)
    assert _digest(tmp_path) == digest
