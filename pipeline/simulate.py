"""Simulate stage: a scene's sequences stepped by the scene's solver (`solver.kind`, pipeline/solvers/), one run file
per sequence.

CLI:
  python -m pipeline.simulate LEVEL SETTINGS.json GROUP [GROUP ...] [--settled RUN] [--device D] [--threads N]
                              [--quiet]
A GROUP is one sequence's files, its scene file (results/<scene>/sequences/<name>/scene.h5, which also sets the
frame count) first and its output last; what lies between is the level's (the runs a solver kind makes). The XPBD
cloth (pipeline/solvers/xpbd.py) makes two:
  low   SCENE.h5 OUT.h5                           the low-res run
  high  SCENE.h5 SUBDIV.h5 SIM_LOW.h5 OUT.h5      the high-res run, held to the low-res one by harmonic test functions
A motion library's window starts from the cloth settled once at rest for the whole scene: the last frame of
--settled, the run of results/<scene>/settle/ at the same level (scenes.sequences.SETTLE).
Several sequences (of one garment) are stepped together as one batch, a solver world each: on a GPU a batch costs
about what one sequence does until the device is full (the workflow's `shard` key sizes it). A batch's
per-sequence work outside the solver runs on --threads threads, a sequence each: the adapter's before stepping,
and, while the device steps the next frames, each stepped chunk's measures (the cloth's harmonic residual) and its
writing (a 64-sequence GPU job's wall is ~1.2x its stepping, docs/performance.md).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

import numpy as np
import warp as wp
from tqdm import tqdm

from pipeline.artifacts.scene import read_library_window, read_rest_mesh
from pipeline.artifacts.simulation import SimulationRun, SimulationWriter, read_last_frame, simulation_writer
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import (SOURCE_MESH, check_same_mesh, dropped_reason, mesh_fingerprint, source_mesh_of,
                              write_dropped)
from pipeline.solvers.level import Level, PreparedBatch
from pipeline.solvers.registry import KINDS, level_names, solver_level
from sim.solver import UnstableSimulation

STEPPED_CHUNK = 16     # frames handed to run_frames' `stepped` at a time
IMPORTED = time.perf_counter()      # the job's wall (its benchmark) less the time since: starting and importing


def run_frames(batch: PreparedBatch, first_frame: np.ndarray, quiet: bool,
               stepped: Callable[[np.ndarray, int, int], None]) -> tuple[np.ndarray, np.ndarray]:
    """Step frames 1..n-1 of the batch, n its longest sequence's frames, from `first_frame` (B, V, 3), the state
    at frame 0. Returns positions (F, B, V, 3) and the ms each frame took the whole batch. `stepped(positions,
    first, end)` is told each time frames first..end-1 are in positions (STEPPED_CHUNK frames at a time, the last
    chunk shorter). Unless `quiet`, says first how much work that is."""
    solver, label = batch.solver, batch.label
    n_frames, worlds = max(batch.n_frames), solver.worlds
    if not quiet:
        # What the batch costs, said before it is stepped (a library's windows are many gigabytes at high res).
        frame_bytes = first_frame[0].size * np.dtype(np.float32).itemsize
        print(f"{label}: {worlds} sequence(s) x {n_frames - 1} frames x {batch.work}; {frame_bytes / 1e6:.3g} MB "
              f"a frame a sequence, {frame_bytes * sum(batch.n_frames) / 1e9:.3g} GB of positions in all, held in "
              f"memory while stepping", file=sys.stderr)
    positions = np.empty((n_frames, *first_frame.shape), dtype=np.float32)
    positions[0] = first_frame
    solve_ms = np.zeros(n_frames)
    first = 0                       # the first frame not yet handed to `stepped`
    for f in tqdm(range(1, n_frames), desc=label, disable=quiet, unit="frame"):
        start = time.perf_counter()
        try:
            solver.step(solver.state, batch.inputs(f))
        except UnstableSimulation as err:
            raise WorldBlewUp(err.world, f"{batch.scene_paths[err.world]}: {label}: simulation blew up "
                                         f"({err.cause}) at frame {f}, substep {err.substep}") from None
        positions[f] = solver.state.read_world_positions()
        solve_ms[f] = (time.perf_counter() - start) * 1e3
        if f + 1 - first == STEPPED_CHUNK:
            stepped(positions, first, f + 1)
            first = f + 1
    if first < n_frames:
        stepped(positions, first, n_frames)
    return positions, solve_ms


class WorldBlewUp(PipelineError):
    """World `world` of a batch blew up: the message names its scene file, the frame and the substep."""

    def __init__(self, world: int, message: str):
        super().__init__(message)
        self.world = world


OpenRun = Callable[[int, tuple[int, int]], SimulationWriter]    # (sequence, (frames, vertices)) -> its writer


def simulate(level: Level, settings: dict, groups: Sequence[tuple[str, ...]], device: str, quiet: bool,
             threads: int, open_run: OpenRun, settled: np.ndarray | None = None
             ) -> tuple[list[SimulationRun], list[SimulationWriter]]:
    """The runs of a batch of sequences (each group its input files and its output last), and their writers,
    which hold every frame already (the caller finishes them with the runs): each chunk of stepped frames is
    measured and written on `threads` threads while the next ones are stepped. `settled`: where a sequence that
    starts settled starts (settled_cloth)."""
    start = time.perf_counter()
    batch = level.prepare(settings, [group[:-1] for group in groups], device, quiet, threads, settled)
    setup = time.perf_counter() - start
    first_frame = batch.solver.state.read_world_positions()
    writers = [open_run(w, (n, first_frame.shape[1])) for w, n in enumerate(batch.n_frames)]

    def record(w: int, first: int, end: int, positions: np.ndarray) -> None:
        end = min(end, batch.n_frames[w])       # a shorter sequence's extra frames are not stored
        if first < end:
            if batch.measure is not None:
                batch.measure(w, first, end, positions)
            writers[w].frames(first, positions[first:end, w])

    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = []

        def stepped(positions: np.ndarray, first: int, end: int) -> None:
            pending.extend(pool.submit(record, w, first, end, positions) for w in range(len(writers)))

        positions, solve_ms = run_frames(batch, first_frame, quiet, stepped)
        stepped_done = time.perf_counter()
        for job in pending:
            job.result()
    if not quiet:
        print(f"{batch.label}: the last chunks' measures and writing after stepping: "
              f"{time.perf_counter() - stepped_done:.1f} s", file=sys.stderr)
        if batch.summary is not None and (said := batch.summary()):
            print(f"{batch.label}: {said}", file=sys.stderr)
    runs = [batch.run(w, positions[:n, w], solve_ms[:n], setup) for w, n in enumerate(batch.n_frames)]
    if batch.tangled is not None:
        runs = [dataclasses.replace(run, dropped=batch.tangled(run.positions)) if droppable(path) else run
                for run, path in zip(runs, batch.scene_paths)]
    return runs, writers


def settled_cloth(run_path: str, scene_path: str) -> np.ndarray:
    """The last frame (V, 3) of a scene's settle run (results/<scene>/settle/sim_<level>.h5), where a motion
    library's windows start; an error if the run is of another mesh than the scene `scene_path`."""
    check_same_mesh(run_path, scene_path)
    return read_last_frame(run_path)


def droppable(scene_path: str) -> bool:
    """Whether a sequence may be dropped rather than stop the run: a motion library's window (one clip among
    many), not a program or a held-out clip the config names."""
    return read_library_window(scene_path) is not None


def dropped_inputs(group: Sequence[str]) -> str:
    """Why a sequence's run cannot be made: an input (its scene file, a high-res run's low-res one) that stands
    for a dropped sequence (pipeline.core.h5.write_dropped), "" if none does."""
    for path in group:
        if path.endswith(".h5") and (reason := dropped_reason(path)):
            return f"{path}: dropped: {reason}"
    return ""


def sequence_groups(level: str, inputs: tuple[str, ...], files: Sequence[str]) -> list[tuple[str, ...]]:
    """The CLI's sequences: groups of the level's `inputs` and OUT."""
    size = len(inputs) + 1
    if len(files) % size:
        raise PipelineError(f"simulate {level} takes groups of {' '.join(inputs)} OUT; got {len(files)} paths")
    return [tuple(files[i:i + size]) for i in range(0, len(files), size)]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.simulate", description=__doc__.splitlines()[0])
    parser.add_argument("level", choices=level_names(), help="the run to make: " + "; ".join(
        f"{name} ({kind}): {level.meaning}" for kind, levels in KINDS.items() for name, level in levels.items()))
    parser.add_argument("settings")
    parser.add_argument("files", nargs="+", metavar="PATH", help="; ".join(
        f"{name} ({kind}): {' '.join(level.inputs)} OUT [...]" for kind, levels in KINDS.items()
        for name, level in levels.items()))
    parser.add_argument("--device", help="Warp device (cpu, cuda:0); default: the settings' device")
    parser.add_argument("--threads", type=int, default=1,
                        help="sequences whose work outside the solver is done at once (Snakemake: the rule's "
                             "threads)")
    parser.add_argument("--settled", metavar="RUN", help="the scene's settle run at this level "
                        "(results/<scene>/settle/sim_LEVEL.h5): a sequence whose scene starts settled (a motion "
                        "library's window) starts from its last frame")
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    if args.threads < 1:
        raise PipelineError(f"--threads {args.threads}: give at least 1")
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    level = solver_level(settings, args.level, args.settings)
    groups = sequence_groups(args.level, level.inputs, args.files)
    device = args.device or settings["device"]
    cli.check_device(device, "Warp", wp.get_cuda_device_count)

    stage = f"simulate_{args.level}"
    # A sequence dropped before (its scene, or its low-res run) gets a dropped run: no work, the reason passed on.
    # A library window whose world blows up is dropped and the batch stepped again without it.
    remaining = []
    for group in groups:
        reason = dropped_inputs(group[:-1])
        if reason:
            write_dropped(group[-1], stage, settings, reason, {SOURCE_MESH: source_mesh_of(group[0]) or ""})
            print(f"{group[-1]}: dropped: {reason}", file=sys.stderr)
        else:
            remaining.append(group)
    runs = []

    # Both from a sequence still to be stepped: a dropped sequence's scene file holds no mesh (and a shard of a
    # library's windows, batched by length, may begin with one).
    @functools.cache
    def source_mesh() -> str:       # asked for once the adapter has checked the scene files
        return mesh_fingerprint(*read_rest_mesh(remaining[0][0]))

    settled = settled_cloth(args.settled, remaining[0][0]) if args.settled and remaining else None
    while remaining and not runs:
        try:
            with contextlib.ExitStack() as outputs:
                def open_run(w: int, frames_vertices: tuple[int, int]) -> SimulationWriter:
                    return outputs.enter_context(simulation_writer(remaining[w][-1], args.level, settings,
                                                                   frames_vertices, device, source_mesh()))

                runs, writers = simulate(level, settings, remaining, device, args.quiet, args.threads, open_run,
                                         settled)
                start = time.perf_counter()
                for writer, run in zip(writers, runs):
                    writer.finish(run)
        except WorldBlewUp as err:
            group = remaining.pop(err.world)
            if not droppable(group[0]):
                raise
            write_dropped(group[-1], stage, settings, str(err), {SOURCE_MESH: source_mesh()})
            print(f"{group[-1]}: dropped: {err}; the others are stepped again", file=sys.stderr)
    if not runs:
        return
    for group, run in zip(remaining, runs):
        if run.dropped:
            print(f"{group[-1]}: dropped: {run.dropped}", file=sys.stderr)
    if not args.quiet:    # where the stage's time went (issue 12: its wall against its stepping)
        ms = runs[0].solve_ms
        print(f"simulate {args.level}: setup {runs[0].setup_seconds:.1f} s, first frame (compiling, capture) "
              f"{ms[1] / 1e3 if len(ms) > 1 else 0.0:.1f} s, the other frames {ms[2:].sum() / 1e3:.1f} s, finishing "
              f"{len(runs)} file(s) {time.perf_counter() - start:.1f} s (frames written while stepping); "
              f"{time.perf_counter() - IMPORTED:.1f} s since the imports", file=sys.stderr)


if __name__ == "__main__":
    cli.run(main)
