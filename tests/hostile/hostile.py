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

import numpy as np

from geometry.loop_subdivision import loop_subdivide
from pipeline import scene
from pipeline.core import cli
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, mesh_fingerprint, write_csr
from pipeline.core.config import load_config, resolve_scene, shared_settings, write_settings

REPO = Path(__file__).resolve().parents[2]
N_FRAMES = 8
# The solver settings a run records (pipeline.simulate): the dataset reads its frame time and gravity there.
SIM_CONFIG = {"solver": {"dt": 0.1, "gravity": [0.0, -9.81, 0.0]}}
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


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n square in the xy plane, CCW faces seen from +z."""
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    vertices = np.stack([c.ravel() / (n - 1) - 0.5, 1.0 - r.ravel() / (n - 1), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, d, e = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return vertices, np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])


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


def write_simulations(folder: Path, n: int = 5) -> None:
    """subdiv.h5 of a sheet (one Loop subdivision level) and, in sequence/, sim_low.h5 and sim_high.h5 of it
    waving, each marked as made from that sheet."""
    vertices, faces = grid(n)
    source_mesh = mesh_fingerprint(vertices, faces)
    subdivision, high_faces = loop_subdivide(vertices, faces, 1)
    t = np.arange(N_FRAMES)[:, None]
    low = np.repeat(vertices[None], N_FRAMES, axis=0)
    low[:, :, 2] = 0.1 * np.sin(3 * vertices[:, 0] + 0.5 * t) * (1 - vertices[:, 1])
    smooth = np.stack([subdivision @ x for x in low])
    high = smooth + 0.01 * np.sin(12 * smooth[:, :, 0] + 0.3 * t)[..., None] * np.array([0.0, 0.0, 1.0])
    for name, positions, f in (("sim_low", low, faces), ("sim_high", high, high_faces)):
        with atomic_h5(folder / "sequence" / f"{name}.h5", "simulate", SIM_CONFIG) as out:
            out["positions"] = positions.astype(np.float32)
            out["faces"] = f.astype(np.int32)
            out.attrs[SOURCE_MESH] = source_mesh
    with atomic_h5(folder / "subdiv.h5", "subdivide") as out:
        out.attrs[SOURCE_MESH] = source_mesh
        write_csr(out, "S", subdivision)
        out["vertices"] = subdivision @ vertices
        out["faces"] = high_faces.astype(np.int32)
