"""The XPBD cloth's adapter: what turns a scene's artifacts into sim.xpbd's model and per-frame inputs, for the two
runs it makes of a sequence (LEVELS):
- `low`: the low-res run (SCENE): the scene's rest mesh, pins following their targets, bending, body and self
  collision as the scene asks;
- `high`: the high-res run (SCENE SUBDIV SIM_LOW) on the subdivided mesh: the same pins carried over through the
  subdivision, the same body, and the hard constraint B^T M (x_high - S x_low) = 0 to the low-res run (paper sec.
  5, Kavan et al. 2011; projected once a substep by default, `high_res.harmonic_every`), starting at S x_low of
  frame 0. Its per-sequence work outside the solver (the harmonic targets before stepping, the residual's
  products while the device steps on) runs on the job's threads, a sequence each;
- `free`: the high-res run without that constraint, from the same start: the scene's physics alone (body and self
  collision where it has them), the paper's high-res reference (a simulation that replaces the learned path, not
  one held to a low-res run). Its harmonic residual says how far it drifts from the low-res run; the trade-off
  times it (experiments.tradeoff).
Several sequences of one garment are one batch, a solver world each. A motion library's window starts at both
levels from the cloth that the scene's settle sequence left (the last frame of that sequence's run at the same
level, the stage's --settled), not from the rest shape: the settle at rest is the same for every window.
"""
from __future__ import annotations

import functools
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from geometry.mesh import unique_edges
from geometry.rigid import apply_rigid
from pipeline.artifacts.scene import SceneDrive, read_rest_mesh, read_scene_drive
from pipeline.artifacts.simulation import SimulationRun, harmonic_residual, read_trajectory
from pipeline.artifacts.subdiv import read_harmonics, read_subdivision
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import check_same_mesh, mesh_fingerprint
from pipeline.core.meshio import check_mesh
from pipeline.solvers.harmonic_targets import BasisProducts, harmonic_targets_of
from pipeline.solvers.level import Level, PreparedBatch, frame_of_each
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, harmonic_constraint
from sim.xpbd.clearance import SubdividedOutsideBody


def solver_settings(settings: dict) -> SolverSettings:
    """The scene's solver, physics and high_res settings as the solver's (`solver.kind` names the solver, it is
    not one of its settings)."""
    solver = {key: value for key, value in settings["solver"].items() if key != "kind"}
    solver["gravity"] = tuple(solver["gravity"])
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


@dataclass(frozen=True)
class ClothBatch:
    """The sequences a simulate job steps together (one world each): their scene files and drives, checked to
    share the mesh, the pinned vertices and the body's shape."""
    scene_paths: list[str]
    drives: list[SceneDrive]
    mesh: str                      # mesh_fingerprint of the shared low-res rest mesh

    @property
    def n_frames(self) -> list[int]:
        return [d.n_frames for d in self.drives]

    @property
    def capsule_radii(self) -> np.ndarray | None:
        """The body's shape, the same in every sequence (None without body collision)."""
        return self.drives[0].capsule_radii

    def initial_positions(self, unsettled: Callable[[int], np.ndarray], settled: np.ndarray | None) -> np.ndarray:
        """(B, V, 3) where each world's cloth starts: `settled` (the settle run's last frame) for a sequence whose
        scene starts settled, `unsettled(w)` for the others; an error naming the scene where `settled` is missing
        or of another mesh."""
        starts = []
        for w, (drive, path) in enumerate(zip(self.drives, self.scene_paths)):
            start = unsettled(w)
            if drive.settled_start:
                if settled is None or settled.shape != start.shape:
                    raise PipelineError(f"{path}: starts from the scene's settled cloth: give the settle run of its "
                                        f"mesh (--settled results/<scene>/settle/sim_<level>.h5)")
                start = settled
            starts.append(start)
        return np.stack(starts)

    def capsules(self, f: int) -> np.ndarray | None:
        """(B, N, 2, 3) frame f's capsules of every sequence (None without body collision)."""
        return None if self.drives[0].capsules is None else frame_of_each([d.capsules for d in self.drives], f)

    def model(self, rest_vertices: np.ndarray, faces: np.ndarray, settings: SolverSettings, pinned: np.ndarray,
              **harmonic) -> ClothModel:
        """The batch's cloth model on a mesh of its garment; an error names the first scene file, whose body
        shape every sequence shares."""
        try:
            return ClothModel(rest_vertices, faces, settings, pinned, capsule_radii=self.capsule_radii, **harmonic)
        except ValueError as err:
            raise PipelineError(f"{self.scene_paths[0]}: {err}") from None


def read_batch(scene_paths: Sequence[str], body_collision: bool) -> ClothBatch:
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
    return ClothBatch(list(scene_paths), drives, mesh)


# A tangled run: a cloth caught between limbs is pulled far beyond its rest lengths over a part of its surface. It
# is judged on the low-res run, which the high-res one follows (a tangled low-res run drops both): the high-res
# run's stretch also measures its solver budget (the test suite's tiny pants, 2 x 10 iterations, reach 6.5 % for
# a few frames in good runs). Low-res runs of the CPU-profile pants (4 programs and a walk) and of the tiny pants
# (three real clips) stretched at most 0.8 and 0.9 % of their edges beyond 1.5x in any frame (2026-11-26); a run
# with five times that share is dropped.
TANGLE_STRETCH = 1.5
TANGLE_EDGE_SHARE = 0.05


def tangle_check(rest: np.ndarray, faces: np.ndarray):
    """Why a run of the mesh tangled (positions (F, V, 3) -> a reason, "" if it did not): in some frame more than
    TANGLE_EDGE_SHARE of its edges are longer than TANGLE_STRETCH times their rest length."""
    edges = unique_edges(faces)
    rest_length = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)

    def tangled(positions: np.ndarray) -> str:
        stretch = np.linalg.norm(positions[:, edges[:, 0]] - positions[:, edges[:, 1]], axis=2) / rest_length
        share = (stretch > TANGLE_STRETCH).mean(axis=1)
        frame = int(np.argmax(share))
        if share[frame] <= TANGLE_EDGE_SHARE:
            return ""
        return (f"tangled: at frame {frame} {share[frame]:.0%} of the edges are stretched beyond "
                f"{TANGLE_STRETCH:g}x their rest length (at most {TANGLE_EDGE_SHARE:.0%} allowed)")
    return tangled


def frame_work(solver: ClothSolver) -> str:
    """What one frame of one world costs and how it is launched, for the log (the schema bounds substeps and
    iterations)."""
    s = solver.model.settings
    return (f"{s.substeps} substeps x {s.iterations} iterations over {solver.world_vertices:,} vertices and "
            f"{solver.n_constraints:,} constraints ({solver.launch_summary()})")


def contact_growth(solver: ClothSolver) -> str:
    """The self-contact lists' room and how many frames filled it and were stepped again (a batch's cost beyond
    its frames: issue 35 saw dance-heavy shards at a quarter of the fastest ones' rate)."""
    if not solver.model.settings.self_collision:
        return ""
    return (f"self-contact lists: room for {solver.contacts.vertex_contacts.shape[1]} entries, "
            f"{solver.frames_stepped_again} frame(s) stepped again after filling them")


def prepare_low(settings: dict, groups: Sequence[tuple[str, ...]], device: str, quiet: bool,
                threads: int, settled: np.ndarray | None) -> PreparedBatch:
    """The low-res runs of a batch of sequences, each group (SCENE,), from the rest shape or `settled`."""
    scene_paths = [group[0] for group in groups]
    s = solver_settings(settings)
    batch = read_batch(scene_paths, s.body_collision)
    rest, faces = read_rest_mesh(scene_paths[0])
    pin_ids = batch.drives[0].pins.ids
    solver = ClothSolver(batch.model(rest, faces, s, pin_ids), device, worlds=len(scene_paths),
                         initial_inputs=FrameInputs(capsules=batch.capsules(0)),
                         initial_positions=batch.initial_positions(lambda w: rest, settled))
    targets = [d.pins.targets for d in batch.drives]

    def inputs(f: int) -> FrameInputs:
        return FrameInputs(pin_targets=frame_of_each(targets, f), capsules=batch.capsules(f))

    def run(w: int, positions: np.ndarray, solve_ms: np.ndarray, setup_seconds: float) -> SimulationRun:
        return SimulationRun(positions, faces, rest, pin_ids, solve_ms, solver.n_constraints,
                             batch_worlds=solver.worlds, setup_seconds=setup_seconds)

    return PreparedBatch("low-res", solver, scene_paths, batch.n_frames, frame_work(solver), inputs, run,
                         tangled=tangle_check(rest, faces), summary=lambda: contact_growth(solver))


def prepare_high(settings: dict, groups: Sequence[tuple[str, ...]], device: str, quiet: bool,
                 threads: int, settled: np.ndarray | None, held: bool = True) -> PreparedBatch:
    """The high-res runs of a batch of sequences, each group (SCENE, SUBDIV, SIM_LOW), one subdivision, from S
    x_low of frame 0 or, for a sequence that starts settled, from `settled` (held to its low-res run's frame 0); each
    sequence's harmonic targets (here) and residual (`measure`, while the device steps on) computed on `threads`
    threads (numpy, scipy and the products release the GIL; the same numbers whatever the count). `held`: with
    the harmonic constraint to the low-res run; without it (the `free` level) the targets only measure the
    residual."""
    start = time.perf_counter()
    if len({group[1] for group in groups}) > 1:
        raise PipelineError(f"{groups[1][1]}: a batch is one garment: every sequence takes the same SUBDIV")
    scene_paths, subdiv_path, low_paths = [group[0] for group in groups], groups[0][1], [group[2] for group in groups]
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
    clearance = (SubdividedOutsideBody(S, batch.capsule_radii, s.collision_thickness, device)
                 if s.body_collision else None)
    # Each sequence's clearance here, one after another (~3 ms a paper-pants sequence on the H100: Warp's launches
    # stay on this thread), then the targets' products on the job's threads while this thread builds the solver
    # from frame 0's (~1 s each, for a 64-sequence batch).
    moved = [clearance(x_low, d.capsules) if clearance else None for x_low, d in zip(x_lows, batch.drives)]
    clearance_done = time.perf_counter()
    model = batch.model(rest, faces, s, pins, harmonic=constraint if held else None)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        computing = [pool.submit(harmonic_targets_of, x_low, products, m) for x_low, m in zip(x_lows, moved)]
        frame0_targets = [harmonic_targets_of(x_low[:1], products, None if m is None else (m[0], m[1][:1]))
                          for x_low, m in zip(x_lows, moved)]
        solver = ClothSolver(model, device, worlds=len(scene_paths),
                             initial_inputs=FrameInputs(harmonic_target=np.concatenate(frame0_targets),
                                                        capsules=batch.capsules(0)),
                             initial_positions=batch.initial_positions(lambda w: S @ x_lows[w][0], settled))
        solver_done = time.perf_counter()
        harmonic_targets = [job.result() for job in computing]
    if not quiet:   # where the setup goes (issue 12: a batch job's wall against its stepping)
        print(f"high-res setup: reading {read_done - start:.1f} s, body clearance {clearance_done - read_done:.1f} s, "
              f"solver {solver_done - clearance_done:.1f} s with the harmonic targets' products on {threads} "
              f"thread(s) meanwhile, then waiting for those {time.perf_counter() - solver_done:.1f} s",
              file=sys.stderr)

    def inputs(f: int) -> FrameInputs:
        return FrameInputs(pin_targets=frame_of_each(targets, f), harmonic_target=frame_of_each(harmonic_targets, f),
                           capsules=batch.capsules(f))

    # B^T M x of the stepped frames for the residual, on the job's threads while the device steps the next ones
    # (numpy's BLAS releases the GIL; the main thread mostly waits on the device).
    contents = [np.empty((n, basis.shape[1], 3)) for n in batch.n_frames]

    def measure(w: int, first: int, end: int, positions: np.ndarray) -> None:
        contents[w][first:end] = products.high(positions[first:end, w])

    def run(w: int, positions: np.ndarray, solve_ms: np.ndarray, setup_seconds: float) -> SimulationRun:
        n_frames = len(positions)
        residual = (np.linalg.norm((contents[w] - harmonic_targets[w]).reshape(n_frames, -1), axis=1)
                    / np.linalg.norm(contents[w].reshape(n_frames, -1), axis=1))
        return SimulationRun(positions, faces, rest, pins, solve_ms, solver.n_constraints,
                             (harmonic_residual(residual, basis.shape[1]),), batch_worlds=solver.worlds,
                             setup_seconds=setup_seconds)

    return PreparedBatch("high-res" if held else "high-res (free)", solver, scene_paths, batch.n_frames,
                         frame_work(solver), inputs, run, measure, summary=lambda: contact_growth(solver))


LEVELS = {
    "low": Level(("SCENE",), "the low-res run", prepare_low),
    "high": Level(("SCENE", "SUBDIV", "SIM_LOW"), "the high-res run held to the low-res one", prepare_high),
    "free": Level(("SCENE", "SUBDIV", "SIM_LOW"), "the high-res run from the same start, not held to the low-res "
                                                  "one (the paper's reference)", functools.partial(prepare_high,
                                                                                                 held=False)),
}
