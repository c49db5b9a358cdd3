"""What projecting onto the harmonic constraint once per substep instead of after every iteration costs and changes.

Pants on the dancing mannequin (bench/batched_sim.py's case: B worlds, world w w frames ahead in the dance), body +
self collision, 8 substeps x 75 iterations: the low-res run, then the high-res run held to it (V/40 modes) with
each schedule. Per schedule: median ms per batch frame after warm-up, the harmonic residual
|B^T M (x - S x_low)| / |B^T M x| over all frames and worlds (median, max: the simulate stage's measure), and how
far the positions move from those of the every-iteration schedule (mean and max vertex distance, mm). Usage:
  python bench/harmonic_schedule.py [--device cuda:0] [--worlds 8] [--frames 60] [--warmup 3] [--out table.md]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from batched_sim import harmonics, pants
from geometry.loop_subdivision import loop_subdivide
from sim.xpbd import ClothSolver, FrameInputs, SolverSettings


def run(vertices, faces, settings, device, pins, targets, capsules, radii, worlds, frames, harmonic=None,
        harmonic_targets=None, initial=None):
    """(F, B, V, 3) positions (frame 0 the initial state) and the ms of each frame after frame 0."""
    extra = {} if harmonic is None else dict(harmonic=harmonic, harmonic_target=harmonic_targets[0])
    solver = ClothSolver(vertices, faces, settings, device, pins, capsules=capsules[:worlds], capsule_radii=radii,
                         worlds=worlds, initial_positions=initial, **extra)
    positions, times = [solver.state.read_world_positions().copy()], []
    for f in range(1, frames):
        shifted = np.arange(worlds) + f
        inputs = FrameInputs(pin_targets=targets[shifted], capsules=capsules[shifted],
                             harmonic_target=None if harmonic is None else harmonic_targets[f])
        start = time.perf_counter()
        solver.step(solver.state, inputs)
        positions.append(solver.state.read_world_positions().copy())
        times.append((time.perf_counter() - start) * 1e3)
    return np.stack(positions).astype(np.float64), np.array(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--out")
    args = parser.parse_args()
    levels, pins, targets, capsules, radii = pants(args.worlds + args.frames + 1)
    (low, low_faces), (high, high_faces) = levels["low"], levels["high"]
    S, _ = loop_subdivide(low, low_faces, levels=1)
    base = dict(body_collision=True, self_collision=True)
    x_low, _ = run(low, low_faces, SolverSettings(**base), args.device, pins, targets, capsules, radii,
                   args.worlds, args.frames)
    constraint, _ = harmonics(high, high_faces, pins)
    mass_basis_t = constraint.mass_basis.T
    # (F, B, K, 3): B^T M S x_low of every frame and world
    f, b, v, _ = x_low.shape
    subdivided = (S @ x_low.transpose(2, 0, 1, 3).reshape(v, -1)).reshape(-1, f, b, 3).transpose(1, 2, 0, 3)
    harmonic_targets = np.einsum("kv,fbvc->fbkc", mass_basis_t, subdivided)
    rows = ["| harmonic projection | ms per batch frame | residual median | residual max | mean move (mm) | "
            "max move (mm) |", "|---|---|---|---|---|---|"]
    reference = None
    for every in ("iteration", "substep"):
        x, ms = run(high, high_faces, SolverSettings(**base, harmonic_every=every), args.device, pins, targets,
                    capsules, radii, args.worlds, args.frames, constraint, harmonic_targets, S @ low)
        content = np.einsum("kv,fbvc->fbkc", mass_basis_t, x)
        residual = (np.linalg.norm((content - harmonic_targets).reshape(*x.shape[:2], -1), axis=2)
                    / np.linalg.norm(content.reshape(*x.shape[:2], -1), axis=2))[1:]
        reference = x if reference is None else reference
        move = np.linalg.norm(x - reference, axis=-1) * 1e3
        rows.append(f"| every {every} | {np.median(ms[args.warmup:]):.1f} | {np.median(residual):.1e} | "
                    f"{residual.max():.1e} | {move.mean():.2f} | {move.max():.2f} |")
        print(rows[-1], flush=True)
    table = "\n".join(rows)
    print(f"\n{args.device}, pants {len(high)} vertices, {args.worlds} worlds x {args.frames} frames of the dance, "
          f"8 x 75, body + self collision\n{table}")
    if args.out:
        Path(args.out).write_text(table + "\n")


if __name__ == "__main__":
    main()
