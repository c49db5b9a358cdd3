"""Simulate stage: the low-res XPBD run, and the high-res run held to it by harmonic test functions.

CLI:
  python -m pipeline.simulate low  SETTINGS.json SCENE.h5 OUT.h5 [SCENE.h5 OUT.h5 ...] [--device D] [--quiet]
  python -m pipeline.simulate high SETTINGS.json SCENE.h5 SUBDIV.h5 SIM_LOW.h5 OUT.h5 [...] [--device D] [--quiet]
      [--threads N]
SCENE.h5 is one sequence's scene (results/<scene>/sequences/<name>/scene.h5), which also sets the frame count.
Several sequences (of one garment) are stepped together as one batch, a solver world each: on a GPU a batch
costs about what one sequence does until the device is full (the workflow's `shard` key sizes it).
The high-res run follows the same pins (carried over through the subdivision), collides with the same body, and
holds the hard constraint B^T M (x_high - S x_low) = 0 (paper sec. 5, Kavan et al. 2011; projected once a
substep by default, `high_res.harmonic_every`). A batch's per-sequence work outside the solver runs on --threads
threads, a sequence each: the harmonic targets before stepping, and, while the device steps the next frames, the
residual's products and the writing of the frames already stepped (a 64-sequence GPU job's wall is ~1.2x its
stepping, docs/performance.md).
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
import warp as wp
from tqdm import tqdm

from geometry.rigid import apply_rigid
from pipeline.core import cli
from pipeline.core.h5 import check_same_mesh, mesh_fingerprint
from pipeline.artifacts.scene import SceneDrive, read_rest_mesh, read_scene_drive
from pipeline.artifacts.simulation import (SimulationRun, SimulationWriter, read_trajectory, simulation_writer,
                                           write_simulation)
from pipeline.artifacts.subdiv import read_harmonics, read_subdivision
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.meshio import check_mesh
from sim.xpbd import ClothSolver, FrameInputs, SolverSettings, UnstableSimulation, harmonic_constraint
from sim.xpbd.body import SubdividedOutsideBody


def solver_settings(settings: dict) -> SolverSettings:
    solver = dict(settings["solver"], gravity=tuple(settings["solver"]["gravity"]))
    physics = settings["physics"]
    try:
        return SolverSettings(**solver, bending=physics["bending"], body_collision=physics["body_collision"],
                              self_collision=physics["self_collision"],
                              harmonic_every=settings["high_res"]["harmonic_every"],
                              contact_rounds=settings["high_res"]["contact_rounds"],
                              frame_end_rounds=settings["high_res"]["frame_end_rounds"])
    except ValueError as err:
        raise PipelineError(f"scene '{settings['scene']}': {err}") from None


def subdivided_pins(S: sp.csr_matrix, low_pins: np.ndarray, low_part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """High-res vertices that follow the low-res pins, and the rigid group each follows: the even copies of
    pinned vertices (Loop subdivision keeps old vertices first, in order) with their vertex's group, and every
    vertex whose stencil touches pinned vertices only, with the group of its largest stencil weight."""
    pinned = np.zeros(S.shape[1], dtype=bool)
    pinned[low_pins] = True
    free_weight = np.asarray(abs(S) @ (~pinned).astype(np.float64)).ravel()
    high_pins = np.union1d(low_pins, np.flatnonzero(free_weight == 0.0)).astype(np.int64)
    # Largest stencil weight among the pinned columns: for an even copy that is its own vertex.
    strongest = np.asarray(abs(S[high_pins][:, low_pins]).argmax(axis=1)).ravel() if len(low_pins) else []
    return high_pins, np.asarray(low_part, dtype=np.int64)[strongest]


def per_frame_product(A, x: np.ndarray) -> np.ndarray:
    """A @ x[f] for every frame f of x (F, V, C), A (K, V) dense or sparse: one matrix product over all frames at
    once (F x C columns). np.einsum would loop in C without BLAS: minutes for a paper-size batch."""
    n_frames, n_vertices, channels = x.shape
    columns = np.ascontiguousarray(x.transpose(1, 0, 2)).reshape(n_vertices, n_frames * channels)
    return np.asarray(A @ columns).reshape(A.shape[0], n_frames, channels).transpose(1, 0, 2)


class BasisProducts:
    """B^T M x per frame (F, K, 3) of the frames x (F, V, 3) of one garment's high-res runs (`high`), and
    (B^T M S) x_low of its low-res ones (`low`), in float64 with numpy's BLAS. On the host, not the device: a
    job's products run on its threads while the device steps (the residual) or take ~0.1 s a paper-pants sequence
    (the targets), and doing them on a GPU with torch cost the job torch's import (4.3 s on the H100's host)."""

    def __init__(self, mass_basis_t: np.ndarray, S):
        self._high = np.ascontiguousarray(mass_basis_t, dtype=np.float64)
        self._low = np.ascontiguousarray((S.T @ self._high.T).T)      # B^T M S (K, V_low): the targets', factored

    def high(self, x: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
        """B^T M x per frame; with `columns`, over those high-res vertices only (x then (F, len(columns), 3))."""
        A = self._high if columns is None else self._high[:, columns]
        return per_frame_product(A, x.astype(np.float64, copy=False))

    def low(self, x_low: np.ndarray) -> np.ndarray:
        """(B^T M S) x_low per frame: B^T M of S x_low without forming S x_low."""
        return per_frame_product(self._low, x_low.astype(np.float64, copy=False))


def harmonic_targets_of(x_low: np.ndarray, products: BasisProducts,
                        moved: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """B^T M x per frame (F, K, 3) of x = S x_low moved clear of the body: `moved` holds the ids of the vertices
    of S x_low the body moves and their offsets (F, M, 3), as sim.xpbd.body.SubdividedOutsideBody gives them.

    As (B^T M S) x_low plus B^T M of the moved vertices' offsets: the same sum as B^T M x over all V high-res
    vertices, for a product with the V_low coarse ones (1/16) and one with the moved vertices. The whole (K, V)
    product per frame was most of the high-res stage's setup for a 64-world batch (single-threaded BLAS, 2026-11-24).
    """
    targets = products.low(x_low)
    if moved is not None and len(moved[0]):
        targets += products.high(moved[1], moved[0])
    return targets


@dataclass(frozen=True)
class Batch:
    """The sequences a simulate job steps together (one world each): their scene files and drives, checked to
    share the mesh, the pinned vertices and the body's shape."""
    scene_paths: list[str]
    drives: list[SceneDrive]
    mesh: str                      # mesh_fingerprint of the shared low-res rest mesh

    @property
    def n_frames(self) -> int:
        """The longest sequence's frames: the batch steps that many; a shorter sequence's world holds its last
        frame's inputs meanwhile, and its extra frames are dropped."""
        return max(d.n_frames for d in self.drives)

    def stack(self, per_sequence, f: int) -> np.ndarray:
        """(B, ...) frame f of each sequence's per-frame array (its last frame for one that has ended)."""
        return np.stack([a[min(f, len(a) - 1)] for a in per_sequence])

    def body(self) -> dict:
        """ClothSolver constructor arguments for the body at frame 0 (none without body collision)."""
        first = self.drives[0]
        if first.capsules is None:
            return {}
        return {"capsules": self.stack([d.capsules for d in self.drives], 0), "capsule_radii": first.capsule_radii}

    def capsules(self, f: int) -> np.ndarray | None:
        return None if self.drives[0].capsules is None else self.stack([d.capsules for d in self.drives], f)


def read_batch(scene_paths: Sequence[str], body_collision: bool) -> Batch:
    """Each sequence's drive; one error naming the file if a sequence is not of the first one's garment."""
    drives, mesh = [], None
    for path in scene_paths:
        rest, faces = read_rest_mesh(path)
        fingerprint = mesh_fingerprint(rest, faces)
        if mesh is None:    # the others must be this mesh: checked once (8 ms a paper-pants file, 0.5 s for 64)
            check_mesh(path, rest, faces)
        drive = read_scene_drive(path, body_collision)
        if mesh is None:
            mesh, first = fingerprint, drive
        elif fingerprint != mesh:
            raise PipelineError(f"{path}: not the same mesh as {scene_paths[0]}: a batch steps sequences of one "
                                f"garment")
        elif (not np.array_equal(drive.pins.ids, first.pins.ids)
              or (drive.capsule_radii is not None and not np.array_equal(drive.capsule_radii, first.capsule_radii))):
            raise PipelineError(f"{path}: its pinned vertices or body shape differ from those of {scene_paths[0]}")
        drives.append(drive)
    return Batch(list(scene_paths), drives, mesh)


STEPPED_CHUNK = 16     # frames handed to run_frames' `stepped` at a time


def run_frames(solver: ClothSolver, batch: Batch, inputs, label: str, quiet: bool,
               stepped: Callable[[np.ndarray, int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Step frames 1..n-1 of the batch (frame 0 is the initial state); `inputs(f)` gives step()'s FrameInputs for
    frame f. Returns positions (F, B, V, 3) and the ms each frame took the whole batch. `stepped(positions,
    first, end)` is told each time frames first..end-1 are in positions (STEPPED_CHUNK frames at a time, the last
    chunk shorter). Unless `quiet`, says first how much work that is (the schema bounds frames, substeps and
    iterations)."""
    state = solver.state
    n_frames, worlds = batch.n_frames, solver.worlds
    if not quiet:
        s = solver.settings
        print(f"{label}: {worlds} sequence(s) x {n_frames - 1} frames x {s.substeps} substeps x {s.iterations} "
              f"iterations over {solver.world_vertices:,} vertices and {solver.n_constraints:,} constraints",
              file=sys.stderr)
    positions = np.empty((n_frames, worlds, solver.world_vertices, 3), dtype=np.float32)
    positions[0] = state.read_world_positions()
    solve_ms = np.zeros(n_frames)
    first = 0                       # the first frame not yet handed to `stepped`
    for f in tqdm(range(1, n_frames), desc=label, disable=quiet, unit="frame"):
        start = time.perf_counter()
        try:
            solver.step(state, inputs(f))
        except UnstableSimulation as err:
            raise PipelineError(f"{batch.scene_paths[err.world]}: {label}: simulation blew up (NaN or speed > "
                                f"max_speed) at frame {f}, substep {err.substep}") from None
        positions[f] = state.read_world_positions()
        solve_ms[f] = (time.perf_counter() - start) * 1e3
        if stepped is not None and f + 1 - first == STEPPED_CHUNK:
            stepped(positions, first, f + 1)
            first = f + 1
    if stepped is not None and first < n_frames:
        stepped(positions, first, n_frames)
    return positions, solve_ms


def simulate_low(settings: dict, scene_paths: Sequence[str], device: str, quiet: bool) -> list[SimulationRun]:
    """The low-res runs of a batch of sequences, one per scene file."""
    start = time.perf_counter()
    s = solver_settings(settings)
    batch = read_batch(scene_paths, s.body_collision)
    rest, faces = read_rest_mesh(scene_paths[0])
    pin_ids = batch.drives[0].pins.ids
    solver = ClothSolver(rest, faces, s, device, pin_ids, worlds=len(scene_paths), **batch.body())
    targets = [d.pins.targets for d in batch.drives]

    def inputs(f: int) -> FrameInputs:
        return FrameInputs(pin_targets=batch.stack(targets, f), capsules=batch.capsules(f))

    setup = time.perf_counter() - start
    positions, solve_ms = run_frames(solver, batch, inputs, "low-res", quiet)
    return [SimulationRun(positions[:d.n_frames, w], faces, rest, pin_ids, solve_ms[:d.n_frames],
                          solver.n_constraints, batch_worlds=solver.worlds, setup_seconds=setup)
            for w, d in enumerate(batch.drives)]


OpenRun = Callable[[int, tuple[int, int]], SimulationWriter]    # (sequence, (frames, vertices)) -> its writer


def simulate_high(settings: dict, scene_paths: Sequence[str], subdiv_path: str, low_paths: Sequence[str],
                  device: str, quiet: bool, threads: int = 1, open_run: OpenRun | None = None) -> list[SimulationRun]:
    """The high-res runs of a batch of sequences (scene file and low-res run of each), one subdivision; each
    sequence's harmonic targets and residual computed on `threads` threads (numpy, scipy and the products release
    the GIL; the same numbers whatever the count). With `open_run`, each sequence's frames go to its writer while
    the next ones are stepped (the caller finishes the writers with the runs)."""
    start = time.perf_counter()
    s = solver_settings(settings)
    batch = read_batch(scene_paths, s.body_collision)
    for path in (subdiv_path, *low_paths):  # before any work: S of another mesh would multiply without complaint
        check_same_mesh(path, scene_paths[0], batch.mesh)
    subdivision, harmonics = read_subdivision(subdiv_path), read_harmonics(subdiv_path)
    S, rest, faces = subdivision.S, subdivision.vertices, subdivision.faces
    basis, mass = harmonics.basis, harmonics.mass
    x_lows = [read_trajectory(path).positions for path in low_paths]
    read_done = time.perf_counter()
    for x_low, low_path, drive, scene_path in zip(x_lows, low_paths, batch.drives, scene_paths):
        if S.shape != (len(rest), x_low.shape[1]):
            raise PipelineError(f"{subdiv_path}: S is {S.shape}, but the high-res mesh has {len(rest)} vertices and "
                                f"{low_path} has {x_low.shape[1]}")
        if len(x_low) != drive.n_frames:
            raise PipelineError(f"{low_path}: has {len(x_low)} frames, the scene {scene_path} {drive.n_frames}")
    low_pins = batch.drives[0].pins
    pins, part = subdivided_pins(S, low_pins.ids, low_pins.part)
    targets = [apply_rigid(d.pins.transforms[:, part], rest[pins]) for d in batch.drives]
    try:
        constraint = harmonic_constraint(basis, mass, pins)
    except ValueError as err:
        raise PipelineError(f"{subdiv_path}: {err}") from None
    # B^T M (S x_low) per frame: the low-frequency content the high-res run must reproduce. Loop subdivision pulls
    # a convex surface inward, so where the low-res cloth rests on the body S x_low dips into it; a target taken
    # there would pull the cloth into the body at every projection and the contacts would push it back out (the
    # residual stayed at ~1e-3 on the CPU pants). With the body, the target is taken from S x_low moved clear of
    # it, the way the solver moves the cloth, so that one shape meets both constraints.
    products = BasisProducts((mass[:, None] * basis).T, S)
    clearance = (SubdividedOutsideBody(S, batch.drives[0].capsule_radii, s.collision_thickness, device)
                 if s.body_collision else None)
    # Each sequence's clearance here, one after another (~3 ms a paper-pants sequence on the H100: Warp's launches
    # stay on this thread), then the targets' products on the job's threads while this thread builds the solver
    # from frame 0's (~1 s each, for a 64-sequence batch).
    moved = [clearance(x_low, d.capsules) if clearance else None for x_low, d in zip(x_lows, batch.drives)]
    clearance_done = time.perf_counter()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        computing = [pool.submit(harmonic_targets_of, x_low, products, m) for x_low, m in zip(x_lows, moved)]
        frame0_targets = [harmonic_targets_of(x_low[:1], products, None if m is None else (m[0], m[1][:1]))
                          for x_low, m in zip(x_lows, moved)]
        solver = ClothSolver(rest, faces, s, device, pins, initial_positions=np.stack([S @ x[0] for x in x_lows]),
                             harmonic=constraint, harmonic_target=np.concatenate(frame0_targets), worlds=len(scene_paths),
                             **batch.body())
        solver_done = time.perf_counter()
        harmonic_targets = [job.result() for job in computing]
    targets_done = time.perf_counter()

    def inputs(f: int) -> FrameInputs:
        return FrameInputs(pin_targets=batch.stack(targets, f), harmonic_target=batch.stack(harmonic_targets, f),
                           capsules=batch.capsules(f))

    setup_done = time.perf_counter()
    setup = setup_done - start
    if not quiet:   # where the setup goes (issue 12: a batch job's wall against its stepping)
        print(f"high-res setup: reading {read_done - start:.1f} s, body clearance {clearance_done - read_done:.1f} s, "
              f"solver {solver_done - clearance_done:.1f} s with the harmonic targets' products on {threads} "
              f"thread(s) meanwhile, then waiting for those {targets_done - solver_done:.1f} s", file=sys.stderr)
    # B^T M x of the stepped frames for the residual, on the job's threads while the device steps the next ones
    # (numpy's BLAS releases the GIL; the main thread mostly waits on the device).
    # Writing the frames there too took a 64-world job's writing (2.5-4.5 s) off its wall.
    contents = [np.empty((d.n_frames, basis.shape[1], 3)) for d in batch.drives]
    writers = [open_run(w, (d.n_frames, len(rest))) for w, d in enumerate(batch.drives)] if open_run else None

    def content_of(w: int, first: int, end: int, positions: np.ndarray) -> None:
        end = min(end, len(contents[w]))
        if first < end:
            contents[w][first:end] = products.high(positions[first:end, w])
            if writers:
                writers[w].frames(first, positions[first:end, w])

    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = []

        def stepped(positions: np.ndarray, first: int, end: int) -> None:
            pending.extend(pool.submit(content_of, w, first, end, positions) for w in range(len(contents)))

        positions, solve_ms = run_frames(solver, batch, inputs, "high-res", quiet, stepped)
        residuals_start = time.perf_counter()
        for job in pending:
            job.result()

    def run_of(w: int) -> SimulationRun:
        n_frames = batch.drives[w].n_frames
        residual = (np.linalg.norm((contents[w] - harmonic_targets[w]).reshape(n_frames, -1), axis=1)
                    / np.linalg.norm(contents[w].reshape(n_frames, -1), axis=1))
        return SimulationRun(positions[:n_frames, w], faces, rest, pins, solve_ms[:n_frames], solver.n_constraints,
                             residual, basis.shape[1], batch_worlds=solver.worlds, setup_seconds=setup)

    runs = [run_of(w) for w in range(solver.worlds)]
    if not quiet:
        print(f"high-res residuals after stepping: {time.perf_counter() - residuals_start:.1f} s", file=sys.stderr)
    return runs


def sequence_groups(level: str, files: Sequence[str]) -> list[tuple[str, ...]]:
    """The CLI's sequences: (scene, out) pairs for `low`, (scene, subdiv, sim_low, out) groups for `high`."""
    size = 2 if level == "low" else 4
    if len(files) % size:
        names = "SCENE OUT" if level == "low" else "SCENE SUBDIV SIM_LOW OUT"
        raise PipelineError(f"simulate {level} takes groups of {names}; got {len(files)} paths")
    return [tuple(files[i:i + size]) for i in range(0, len(files), size)]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.simulate", description=__doc__.splitlines()[0])
    parser.add_argument("level", choices=("low", "high"), help="the low-res run, or the high-res run constrained "
                                                                "to the low-res one")
    parser.add_argument("settings")
    parser.add_argument("files", nargs="+", metavar="PATH",
                        help="low: SCENE OUT [SCENE OUT ...]; high: SCENE SUBDIV SIM_LOW OUT [...]")
    parser.add_argument("--device", help="Warp device (cpu, cuda:0); default: the settings' device")
    parser.add_argument("--threads", type=int, default=1,
                        help="high: sequences whose harmonic targets and residual are computed at once "
                             "(Snakemake: the rule's threads)")
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    if args.threads < 1:
        raise PipelineError(f"--threads {args.threads}: give at least 1")
    groups = sequence_groups(args.level, args.files)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    device = args.device or settings["device"]
    cli.check_device(device, "Warp", wp.get_cuda_device_count)
    scenes = [group[0] for group in groups]

    @functools.cache
    def source_mesh() -> str:       # asked for once the stage has checked the scene files
        return mesh_fingerprint(*read_rest_mesh(scenes[0]))

    with contextlib.ExitStack() as outputs:
        writers: list[SimulationWriter] = []

        def open_run(w: int, frames_vertices: tuple[int, int]) -> SimulationWriter:
            writers.append(outputs.enter_context(simulation_writer(groups[w][-1], "high", settings, frames_vertices,
                                                                   device, source_mesh())))
            return writers[-1]

        if args.level == "low":
            runs = simulate_low(settings, scenes, device, args.quiet)
        else:
            subdivs = {group[1] for group in groups}
            if len(subdivs) > 1:
                raise PipelineError(f"{groups[1][1]}: a batch is one garment: every sequence takes the same SUBDIV")
            runs = simulate_high(settings, scenes, groups[0][1], [group[2] for group in groups], device,
                                 args.quiet, args.threads, open_run)
        start = time.perf_counter()
        for writer, run in zip(writers, runs):          # a high-res batch: its frames are written already
            writer.finish(run)
        if not writers:
            for group, run in zip(groups, runs):
                write_simulation(group[-1], args.level, settings, run, device, source_mesh())
    if not args.quiet:    # where the stage's time went (issue 12: its wall against its stepping)
        ms = runs[0].solve_ms
        streamed = " (high-res frames written while stepping)" if writers else ""
        print(f"simulate {args.level}: setup {runs[0].setup_seconds:.1f} s, first frame (compiling, capture) "
              f"{ms[1] / 1e3 if len(ms) > 1 else 0.0:.1f} s, the other frames {ms[2:].sum() / 1e3:.1f} s, writing "
              f"{len(runs)} file(s) {time.perf_counter() - start:.1f} s{streamed}", file=sys.stderr)

if __name__ == "__main__":
    cli.run(main)
