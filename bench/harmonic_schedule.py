"""What projecting onto the harmonic constraint once per substep instead of after every iteration costs and changes.

Pants on the moving mannequin (bench/batched_sim.py's case: B worlds, each its own motion from rest), body +
self collision, 8 substeps x 75 iterations: the low-res run, then the high-res run held to it (V/40 modes) with
each schedule. Per schedule: median ms per batch frame after warm-up, the harmonic residual
|B^T M (x - S x_low)| / |B^T M x| over all frames and worlds (median, max: the simulate stage's measure), and how
far the positions move from those of the first row (mean and max vertex distance, mm). `--rounds` adds rows
of the every-substep schedule with other numbers of contact rounds (`high_res.contact_rounds`: friction, then
rounds of clearing the body and projecting, at the end of each substep; "3+9": 9 more after each frame's last
substep, `frame_end_rounds`). Usage:
  python bench/harmonic_schedule.py [--device cuda:0] [--worlds 8] [--frames 60] [--warmup 3]
      [--schedules iteration,substep] [--rounds 3] [--out table.md]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from batched_sim import harmonic_targets, harmonics, pants
from geometry.loop_subdivision import loop_subdivide
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings


def run(vertices, faces, settings, device, pins, targets, capsules, radii, worlds, frames, harmonic=None,
        goals=None, initial=None):
    """(F, B, V, 3) positions (frame 0 the initial state) and the ms of each frame after frame 0."""
    model = ClothModel(vertices, faces, settings, pins, harmonic=harmonic, capsule_radii=radii)
    start = FrameInputs(harmonic_target=None if harmonic is None else goals[0], capsules=capsules[:worlds, 0])
    solver = ClothSolver(model, device, worlds=worlds, initial_inputs=start, initial_positions=initial)
    positions, times = [solver.state.read_world_positions()], []
    for f in range(1, frames):
        inputs = FrameInputs(pin_targets=targets[:worlds, f], capsules=capsules[:worlds, f],
                             harmonic_target=None if harmonic is None else goals[f])
        start = time.perf_counter()
        solver.step(solver.state, inputs)
        positions.append(solver.state.read_world_positions())
        times.append((time.perf_counter() - start) * 1e3)
    return np.stack(positions).astype(np.float64), np.array(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--schedules", default="iteration,substep")
    parser.add_argument("--rounds", default=str(SolverSettings.contact_rounds),
                        help="contact rounds of the every-substep rows, comma-separated; R+E adds E rounds at the "
                             "end of each frame (frame_end_rounds)")
    parser.add_argument("--out")
    args = parser.parse_args()
    levels, pins, targets, capsules, radii = pants(args.frames + 1, args.worlds)
    (low, low_faces), (high, high_faces) = levels["low"], levels["high"]
    S, _ = loop_subdivide(low, low_faces, levels=1)
    base = dict(body_collision=True, self_collision=True)
    x_low, _ = run(low, low_faces, SolverSettings(**base), args.device, pins, targets, capsules, radii,
                   args.worlds, args.frames)
    constraint = harmonics(high, high_faces, pins)
    mass_basis_t = constraint.mass_basis.T
    # (F, B, K, 3)
    goals = harmonic_targets(constraint, S, x_low, capsules, radii, SolverSettings(**base), args.device)
    rows = ["| harmonic projection | contact rounds | ms per batch frame | residual median | residual p99 | "
            "residual max | mean move (mm) | max move (mm) |", "|---|---|---|---|---|---|---|---|"]
    reference = None
    cases = [(every, rounds) for every in args.schedules.split(",")
             for rounds in ([str(SolverSettings.contact_rounds)] if every == "iteration" else args.rounds.split(","))]
    for every, rounds in cases:
        per_substep, _, frame_end = rounds.partition("+")
        settings = SolverSettings(**base, harmonic_every=every, contact_rounds=int(per_substep),
                                  frame_end_rounds=int(frame_end or 0))
        x, ms = run(high, high_faces, settings, args.device, pins, targets, capsules, radii, args.worlds,
                    args.frames, constraint, goals, S @ low)
        content = np.einsum("kv,fbvc->fbkc", mass_basis_t, x, optimize=True)  # BLAS, not a C loop
        residual = (np.linalg.norm((content - goals).reshape(*x.shape[:2], -1), axis=2)
                    / np.linalg.norm(content.reshape(*x.shape[:2], -1), axis=2))[1:]
        reference = x if reference is None else reference
        move = np.linalg.norm(x - reference, axis=-1) * 1e3
        rows.append(f"| every {every} | {rounds} | {np.median(ms[args.warmup:]):.1f} | {np.median(residual):.1e} | "
                    f"{np.quantile(residual, 0.99):.1e} | {residual.max():.1e} | {move.mean():.2f} | "
                    f"{move.max():.2f} |")
        print(rows[-1], flush=True)
    table = "\n".join(rows)
    print(f"\n{args.device}, pants {len(high)} vertices, {args.worlds} worlds x {args.frames} frames of the dance, "
          f"8 x 75, body + self collision\n{table}")
    if args.out:
        Path(args.out).write_text(table + "\n")


if __name__ == "__main__":
    main()
