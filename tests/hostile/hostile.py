"""What every hostile-input test checks, and the small valid artifacts they start from (then spoil).

A refused input must end the stage the way pipeline.core.cli promises: exit status 2, exactly one stderr line
`error: <file>: <problem>`, no traceback, and nothing new left in the output folder (no artifact, no temporary
file). Stages run in a subprocess where a crash is possible (a segfault kills the process, not the test run).
"""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

from pipeline import scene
from pipeline.core import cli
from pipeline.core.config import load_config, resolve_scene, shared_settings, write_settings
from stage_inputs import write_waving_sheet

REPO = Path(__file__).resolve().parents[2]
ARCH = ["--arch", "D8 D16 D D16", "--conv", "RC7"]


@dataclasses.dataclass(frozen=True)
class Run:
    returncode: int
    stderr: str


def run_stage(stage: str, *args, cwd: Path = REPO, timeout: float = 300) -> Run:
    """`python -m pipeline.<stage> ARGS` in its own process."""
    done = subprocess.run([sys.executable, "-m", f"pipeline.{stage}", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)
    return Run(done.returncode, done.stderr)


def run_in_process(main, *args, capsys) -> Run:
    """A stage's main through pipeline.core.cli.run in this process: for checks that happen before any heavy work."""
    try:
        cli.run(main, [str(a) for a in args])
        code = 0
    except SystemExit as exit_info:
        code = exit_info.code
    return Run(code, capsys.readouterr().err)


def files_in(folder: Path) -> set[str]:
    """Every name under `folder`, hidden temporary files included."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def assert_refused(run: Run, *words: str, folder: Path | None = None, before: set[str] | None = None) -> None:
    """Exit 2 with one `error: ` line that holds each of `words`, no traceback; `folder` unchanged since
    `before` (its files_in listing from before the run)."""
    lines = run.stderr.splitlines()
    assert run.returncode == 2, run.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith("error: "), run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])
    if folder is not None:
        assert files_in(folder) == before, files_in(folder) ^ before


def patch_settings() -> dict:
    """What settings.json holds for the patch scene (a 2 x 2 sheet) on the CPU profile."""
    return shared_settings(resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch", "cpu"))


def write_patch_scene(folder: Path) -> None:
    """settings.json of the patch scene and, as scene.h5, the scene of its first sequence."""
    write_settings(patch_settings(), folder / "settings.json")
    scene.main([str(folder / "settings.json"), str(folder / "scene.h5"), "--sequence", "train_000"])


def dataset_command(subdiv: Path, out: Path, folder: Path) -> list[Path | str]:
    """The arguments of `pipeline.dataset` building `out` from `subdiv` and the sequence of `write_simulations`
    in `folder`."""
    return [subdiv, out, folder / "sequence", "--quiet"]


def write_simulations(folder: Path) -> None:
    """subdiv.h5 of a 5 x 5 sheet (one Loop subdivision level) and, in sequence/, sim_low.h5 and sim_high.h5 of it
    waving for 8 frames, each marked as made from that sheet."""
    write_waving_sheet(folder, levels=1, n_frames=8, runs_folder="sequence", source_mesh=True)
