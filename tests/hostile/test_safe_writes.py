"""Item 3 of issue 13: outputs are written through unique temporary files (pipeline.core.h5.atomic_write),
so a link planted at a predictable name is never written through, and two identical runs do not trip over
each other's temporary files."""
from __future__ import annotations

import subprocess
import sys

import torch

from hostile import ARCH, REPO, files_in, run_stage
from pipeline.artifacts.model import MODEL_FORMAT

# The fixed temporary names the stages used to write through, and an output itself.
PLANTED = (".model.pt.tmp", ".model.pt.ckpt.tmp", ".report.md.tmp", ".train.h5.tmp", "model.pt", "report.md")


def test_links_planted_at_output_and_temporary_names_are_not_written_through(valid, tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    for name in PLANTED:
        (out / name).symlink_to(victim)
    trained = run_stage("train", valid / "dataset.h5", valid / "operators.h5", out / "model.pt", out / "train.h5",
                        *ARCH, "--epochs", "2", "--quiet")
    assert trained.returncode == 0, trained.stderr[-3000:]
    evaluated = run_stage("evaluate", valid / "dataset.h5", valid / "operators.h5", out / "model.pt",
                          out / "eval.h5", out / "report.md", "--render-frames", "0", "--export-frames", "1",
                          "--timing-frames", "1", "--quiet")
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    assert victim.read_text() == "precious"
    assert not (out / "model.pt").is_symlink() and not (out / "report.md").is_symlink()
    assert torch.load(out / "model.pt", weights_only=True)["format"] == MODEL_FORMAT
    assert (out / "report.md").read_text().startswith("# Evaluation")
    made = files_in(out) - set(PLANTED)
    assert {name for name in made if name.startswith(".")} == set()          # no temporary file left


def test_two_identical_trainings_at_once_both_finish_cleanly(valid, tmp_path):
    command = [sys.executable, "-m", "pipeline.train", str(valid / "dataset.h5"), str(valid / "operators.h5"),
               str(tmp_path / "model.pt"), str(tmp_path / "train.h5"), *ARCH, "--epochs", "2", "--quiet"]
    runs = [subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for _ in range(2)]
    results = [(run.communicate(timeout=300), run.returncode) for run in runs]
    for (_, stderr), returncode in results:
        assert returncode == 0 and "Traceback" not in stderr, stderr[-3000:]
    assert files_in(tmp_path) == {"model.pt", "train.h5"}                  # no checkpoint, no temporary file
    assert torch.load(tmp_path / "model.pt", weights_only=True)["format"] == MODEL_FORMAT
