"""Simulate stage: the low-res XPBD run, and the high-res run held to it by harmonic test functions.

CLI:
  python -m pipeline.simulate low  SETTINGS.json SCENE.h5 OUT.h5 [--device D] [--quiet]
  python -m pipeline.simulate high SETTINGS.json SCENE.h5 SUBDIV.h5 SIM_LOW.h5 OUT.h5 [--device D] [--quiet]
SCENE.h5 is one sequence's scene (results/<scene>/sequences/<name>/scene.h5), which also sets the frame count.
The high-res run follows the same pins (carried over through the subdivision), collides with the same body, and
holds the hard constraint B^T M (x_high - S x_low) = 0 after every solver iteration (paper sec. 5, Kavan et al.
2011).
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Sequence

import numpy as np
import scipy.sparse as sp
import warp as wp
from tqdm import tqdm

from geometry.rigid import apply_rigid
from pipeline import cli
from pipeline.artifacts.h5 import check_same_mesh, mesh_fingerprint
from pipeline.artifacts.scene import SceneDrive, read_rest_mesh, read_scene_drive
from pipeline.artifacts.simulation import SimulationRun, read_trajectory, write_simulation
from pipeline.artifacts.subdiv import read_harmonics, read_subdivision
from pipeline.config import read_settings
from pipeline.errors import PipelineError
from pipeline.meshio import check_mesh
from sim.xpbd import ClothSolver, FrameInputs, SolverSettings, UnstableSimulation, harmonic_constraint


def solver_settings(settings: dict) -> SolverSettings:
    solver = dict(settings["solver"], gravity=tuple(settings["solver"]["gravity"]))
    physics = settings["physics"]
    try:
        return SolverSettings(**solver, bending=physics["bending"], body_collision=physics["body_collision"],
                              self_collision=physics["self_collision"])
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


def solver_body(drive: SceneDrive) -> dict:
    """ClothSolver constructor arguments for the body at frame 0 (none without body collision)."""
    return {} if drive.capsules is None else {"capsules": drive.capsules[0], "capsule_radii": drive.capsule_radii}


def frame_inputs(drive: SceneDrive, f: int, pin_targets: np.ndarray,
                 harmonic_target: np.ndarray | None = None) -> FrameInputs:
    """ClothSolver.step inputs for frame f."""
    return FrameInputs(pin_targets=pin_targets, harmonic_target=harmonic_target,
                       capsules=None if drive.capsules is None else drive.capsules[f])


def run_frames(solver: ClothSolver, n_frames: int, inputs, label: str, quiet: bool) -> tuple[np.ndarray, np.ndarray]:
    """Step frames 1..n-1 (frame 0 is the initial state); `inputs(f)` gives step()'s FrameInputs for frame f.
    Unless `quiet`, says first how much work that is (the schema bounds frames, substeps and iterations)."""
    state = solver.state
    if not quiet:
        s = solver.settings
        print(f"{label}: {n_frames - 1} frames x {s.substeps} substeps x {s.iterations} iterations over "
              f"{state.positions.shape[0]:,} vertices and {solver.n_constraints:,} constraints", file=sys.stderr)
    positions = np.empty((n_frames, *state.positions.shape, 3), dtype=np.float32)
    positions[0] = state.read_positions()
    solve_ms = np.zeros(n_frames)
    for f in tqdm(range(1, n_frames), desc=label, disable=quiet, unit="frame"):
        start = time.perf_counter()
        try:
            solver.step(state, inputs(f))
        except UnstableSimulation as err:
            raise PipelineError(f"{label}: simulation blew up (NaN or speed > max_speed) at frame {f}, {err}") from None
        positions[f] = state.positions.numpy()
        solve_ms[f] = (time.perf_counter() - start) * 1e3
    return positions, solve_ms


def simulate_low(settings: dict, scene_path: str, device: str, quiet: bool) -> SimulationRun:
    rest, faces = read_rest_mesh(scene_path)
    check_mesh(scene_path, rest, faces)
    s = solver_settings(settings)
    drive = read_scene_drive(scene_path, s.body_collision)
    pins = drive.pins
    solver = ClothSolver(rest, faces, s, device, pins.ids, **solver_body(drive))
    positions, solve_ms = run_frames(solver, drive.n_frames, lambda fr: frame_inputs(drive, fr, pins.targets[fr]),
                                     f"{scene_path} low-res", quiet)
    return SimulationRun(positions, faces, rest, pins.ids, solve_ms, solver.n_constraints)


def simulate_high(settings: dict, scene_path: str, subdiv_path: str, low_path: str, device: str,
                  quiet: bool) -> SimulationRun:
    s = solver_settings(settings)
    drive = read_scene_drive(scene_path, s.body_collision)
    scene_mesh = mesh_fingerprint(*read_rest_mesh(scene_path))
    for path in (subdiv_path, low_path):     # before any work: S of another mesh would multiply without complaint
        check_same_mesh(path, scene_path, scene_mesh)
    subdivision, harmonics = read_subdivision(subdiv_path), read_harmonics(subdiv_path)
    S, rest, faces = subdivision.S, subdivision.vertices, subdivision.faces
    basis, mass = harmonics.basis, harmonics.mass
    x_low = read_trajectory(low_path).positions
    if S.shape != (len(rest), x_low.shape[1]):
        raise PipelineError(f"{subdiv_path}: S is {S.shape}, but the high-res mesh has {len(rest)} vertices and "
                            f"{low_path} has {x_low.shape[1]}")
    if len(x_low) != drive.n_frames:
        raise PipelineError(f"{low_path}: has {len(x_low)} frames, the scene {scene_path} {drive.n_frames}")
    pins, part = subdivided_pins(S, drive.pins.ids, drive.pins.part)
    targets = apply_rigid(drive.pins.transforms[:, part], rest[pins])
    try:
        constraint = harmonic_constraint(basis, mass, pins)
    except ValueError as err:
        raise PipelineError(f"{subdiv_path}: {err}") from None
    # B^T M (S x_low) per frame: the low-frequency content the high-res run must reproduce.
    mass_basis_t = (mass[:, None] * basis).T
    harmonic_targets = np.einsum("kv,fvc->fkc", mass_basis_t, np.stack([S @ x for x in x_low]))
    solver = ClothSolver(rest, faces, s, device, pins, initial_positions=S @ x_low[0],
                         harmonic=constraint, harmonic_target=harmonic_targets[0], **solver_body(drive))

    def inputs(fr: int) -> FrameInputs:
        return frame_inputs(drive, fr, targets[fr], harmonic_targets[fr])

    positions, solve_ms = run_frames(solver, drive.n_frames, inputs, f"{scene_path} high-res", quiet)
    high_content = np.einsum("kv,fvc->fkc", mass_basis_t, positions.astype(np.float64))
    residual = (np.linalg.norm((high_content - harmonic_targets).reshape(len(positions), -1), axis=1)
                / np.linalg.norm(high_content.reshape(len(positions), -1), axis=1))
    return SimulationRun(positions, faces, rest, pins, solve_ms, solver.n_constraints, residual, basis.shape[1])


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.simulate", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="level", required=True)
    low = sub.add_parser("low", help="the low-res run")
    low.add_argument("settings"), low.add_argument("scene"), low.add_argument("out")
    high = sub.add_parser("high", help="the high-res run, constrained to the low-res one")
    for name in ("settings", "scene", "subdiv", "sim_low", "out"):
        high.add_argument(name)
    for p in (low, high):
        p.add_argument("--device", help="Warp device (cpu, cuda:0); default: the settings' device")
        cli.add_quiet(p)
    args = parser.parse_args(argv)
    settings = read_settings(args.settings)
    device = args.device or settings["device"]
    cli.check_device(device, "Warp", wp.get_cuda_device_count)
    if args.level == "low":
        run = simulate_low(settings, args.scene, device, args.quiet)
    else:
        run = simulate_high(settings, args.scene, args.subdiv, args.sim_low, device, args.quiet)
    write_simulation(args.out, args.level, settings, run, device, mesh_fingerprint(*read_rest_mesh(args.scene)))


if __name__ == "__main__":
    cli.run(main)
