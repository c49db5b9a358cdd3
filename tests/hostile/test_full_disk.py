"""Items 1-4, 12, 13 and part of 15 of issue 41: a full disk, stale temporary files, a diverging training,
names with a trailing newline and inputs that are no regular file.

A write the file system refuses (here a file size limit, `prlimit --fsize`: EFBIG like ENOSPC, on any machine
without root) ends every stage with one error naming the output, exit 2 and no temporary file: once it was an
AttributeError traceback (operators, subdivide), a segfault inside h5py's close (simulate), torch's
`unexpected pos` (train) or an OSError traceback (evaluate's renders). pipeline.core.h5 is the one output layer
that makes it so; its temporary files left by a killed run are swept when the output is next written, those
of a live writer never."""
from __future__ import annotations

import copy
import fcntl
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hostile import ARCH, REPO, Run, assert_refused, files_in, run_in_process, write_patch_scene
from pipeline import train
from pipeline.core.config import load_config, validate_config
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, atomic_write

needs_prlimit = pytest.mark.skipif(shutil.which("prlimit") is None, reason="prlimit (util-linux) not installed")


def run_limited(size: int, stage: str, *args):
    """`python -m pipeline.<stage> ARGS` allowed to write files of at most `size` bytes."""
    done = subprocess.run(["prlimit", f"--fsize={size}", sys.executable, "-m", f"pipeline.{stage}", *map(str, args)],
                          capture_output=True, text=True, cwd=REPO, timeout=300)
    return done.returncode, "\n".join(line for line in done.stderr.splitlines() if not _warp_banner(line))


def _warp_banner(line: str) -> bool:
    """Warp's start-up notice (docs/security.md: known gaps), not an error line."""
    return line.startswith(("Warp", "   ", "Module ")) or "CUDA" in line


def assert_one_write_error(result, out: Path, folder: Path, before: set[str]) -> None:
    code, stderr = result
    lines = stderr.splitlines()
    assert code == 2, stderr[-3000:]
    assert lines == [f"error: {out}: cannot write the output (File too large)"], stderr[-3000:]
    assert files_in(folder) == before, files_in(folder) ^ before


@needs_prlimit
@pytest.mark.parametrize("stage", ["subdivide", "operators"])
def test_an_hdf5_output_that_cannot_be_created_is_one_error(valid, tmp_path, stage):
    """Item 1: the error path itself failed (a str path where a Path was expected)."""
    extra = ["--levels", "1"] if stage == "subdivide" else ["--conv", "RC7", "--levels", "2"]
    result = run_limited(0, stage, valid / "subdiv.h5", tmp_path / "out.h5", *extra, "--quiet")
    assert_one_write_error(result, tmp_path / "out.h5", tmp_path, set())


@pytest.fixture(scope="module")
def patch_scene(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("patch")
    write_patch_scene(folder)
    return folder


@needs_prlimit
@pytest.mark.parametrize("size", [0, 4096, 6000, 9000])
def test_a_disk_filling_during_a_simulation_is_one_error_not_a_segfault(patch_scene, tmp_path, size):
    """Item 2: libhdf5 crashed (rc 139) closing a file after failed writes, leaving the temporary file."""
    out = tmp_path / "sim_low.h5"
    result = run_limited(size, "simulate", "low", patch_scene / "settings.json", patch_scene / "scene.h5", out,
                         "--quiet")
    assert_one_write_error(result, out, tmp_path, set())


@needs_prlimit
def test_a_checkpoint_the_disk_cannot_hold_is_one_error(valid, tmp_path):
    """Item 3: torch.save reported the refused write as `RuntimeError ... unexpected pos`."""
    result = run_limited(20000, "train", valid / "dataset.h5", valid / "operators.h5", tmp_path / "model.pt",
                         tmp_path / "train.h5", *ARCH, "--epochs", "1", "--quiet")
    assert_one_write_error(result, tmp_path / "model.pt.ckpt", tmp_path, set())


def test_a_refused_write_is_reported_whatever_the_writer_makes_of_it(tmp_path, monkeypatch):
    """Item 3's root: a writer that swallows the OSError into its own exception (torch, matplotlib, an encoder)
    still ends in the one error naming the output."""
    def full(*args):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(PipelineError, match=r"out\.png: cannot write the output \(No space left on device\)"):
        with atomic_write(tmp_path / "out.png") as f:
            try:
                f.write(b"png")
            except OSError:
                raise RuntimeError("unexpected pos") from None
    assert files_in(tmp_path) == set()


def _stale(folder: Path, name: str) -> Path:
    path = folder / name
    path.write_bytes(b"left by a killed run")
    return path


def test_stale_temporary_files_of_an_output_are_swept(tmp_path):
    """Item 4: a killed stage's temporary files stayed for good, each as large as the partial output. Only this
    output's own names go; another output's, a link and a live writer's (locked) stay."""
    stale = [_stale(tmp_path, ".sim_low.h5.abcd1234.tmp.h5"), _stale(tmp_path, ".sim_low.h5.zz_9zz00.tmp.h5")]
    kept = [_stale(tmp_path, ".sim_high.h5.abcd1234.tmp.h5"), _stale(tmp_path, ".sim_low.h5.abcd1234.tmp"),
            _stale(tmp_path, "sim_low.h5.abcd1234.tmp.h5"), _stale(tmp_path, ".sim_low.h5.abcd12345.tmp.h5")]
    (tmp_path / ".sim_low.h5.linkxxxx.tmp.h5").symlink_to(kept[0])
    live = _stale(tmp_path, ".sim_low.h5.livexxxx.tmp.h5")
    with open(live, "rb") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        with atomic_h5(tmp_path / "sim_low.h5", "test") as f:
            f["x"] = [1.0]
    assert not any(path.exists() for path in stale)
    assert all(path.exists() for path in [*kept, live]) and (tmp_path / ".sim_low.h5.linkxxxx.tmp.h5").is_symlink()


def test_a_diverging_training_is_one_error(valid, tmp_path, capsys, monkeypatch):
    """Item 12: `lr: 1e10` trained to NaN losses, wrote model.pt and exited 0 (and evaluate took that model);
    the schema now bounds training.lr, and an epoch with a non-finite loss ends the stage whatever the rate."""
    monkeypatch.setattr(train, "MAX_LR", math.inf)     # past the CLI's bound, to reach the epoch's check
    run = run_in_process(train.main, valid / "dataset.h5", valid / "operators.h5", tmp_path / "model.pt",
                         tmp_path / "train.h5", *ARCH, "--epochs", "2", "--lr", "1e10", "--quiet", capsys=capsys)
    assert_refused(run, f"{tmp_path / 'model.pt'}: the training loss of epoch 1 is nan", "--lr 1e+10)",
                   folder=tmp_path, before=set())


@pytest.mark.parametrize("edit, words", [
    (lambda c: c["scenes"].__setitem__("evil\n", c["scenes"]["patch"]), r"scenes: 'evil\n' does not match"),
    (lambda c: c["scenes"]["patch"].setdefault("network", {}).__setitem__("conv", "RC9\n"), r"'RC9\n' does not"),
    (lambda c: c["scenes"]["patch"].setdefault("training", {}).__setitem__("lr", 1e38), "lr: 1e+38 is greater"),
])
def test_config_strings_match_their_patterns_whole_and_lr_is_bounded(edit, words):
    """Items 13, 15 (`conv: "RC9\\n"` was a two-line error) and 12: a pattern's `$` matched before a trailing
    newline (jsonschema searches); the error is one line, the newline shown escaped."""
    config = copy.deepcopy(load_config(REPO / "workflow_config.yaml"))
    edit(config)
    with pytest.raises(PipelineError) as refused:
        validate_config(config)
    assert words in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("make, kind", [(lambda p: p.mkdir(), "a folder"), (os.mkfifo, "a FIFO"),
                                        (lambda p: p.symlink_to("/dev/zero"), "a device")])
def test_an_input_that_is_no_regular_file_is_named_for_what_it_is(tmp_path, make, kind):
    """Item 15: a folder, a FIFO or /dev/zero was reported as 'does not exist'."""
    make(tmp_path / "subdiv.h5")
    run = subprocess.run([sys.executable, "-m", "pipeline.operators", tmp_path / "subdiv.h5", tmp_path / "o.h5",
                          "--quiet"], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert_refused(Run(run.returncode, run.stderr), f"{tmp_path / 'subdiv.h5'}: input is {kind}, not a regular file")


@needs_prlimit
def test_an_evaluation_the_disk_cannot_hold_is_one_error_and_leaves_nothing(valid, tmp_path):
    """Item 3: evaluate's renders ended in an OSError traceback. Its stills are larger than the limit here: one
    error, nothing of the evaluation left (no report, no eval.h5, no staging folder)."""
    model = tmp_path / "trained"
    model.mkdir()
    code, stderr = run_limited(10 ** 9, "train", valid / "dataset.h5", valid / "operators.h5", model / "model.pt",
                               model / "train.h5", *ARCH, "--epochs", "1", "--quiet")
    assert code == 0, stderr
    out = tmp_path / "out"
    out.mkdir()
    code, stderr = run_limited(30000, "evaluate", valid / "dataset.h5", valid / "operators.h5", model / "model.pt",
                               out / "eval.h5", out / "report.md", "--render-frames", "2", "--video-frames", "0",
                               "--export-frames", "0", "--timing-frames", "1", "--quiet")
    lines = stderr.splitlines()
    assert code == 2 and len(lines) == 1, stderr[-3000:]
    assert lines[0].startswith("error: ") and "cannot write the output (File too large)" in lines[0]
    assert files_in(out) == set(), files_in(out)
