"""Batched simulation throughput: cloth-frames per second against the number of worlds B stepped together.

Pants worn by the mannequin, low-res (~3.7k vertices) and one Loop level finer (~14.5k), body + self collision,
the paper's 8 substeps x 75 iterations; world w plays the dance shifted by w frames (each its own body motion and
pins), and the high-res rows also hold every world to a harmonic target (V/40 modes, as the simulate stage does).
Per B: median ms per batch frame over measured frames after warm-up (the first frames compile and capture the
graph), cloth-frames/s = B * 1000 / ms, and the ratio to B = 1 in the same run. `--profile` adds where one frame's
time goes, per kernel, at the largest B (CUDA only; launched without the graph, so each kernel is timed on its
own). Usage:
  python bench/batched_sim.py [--device cuda:0] [--levels low,high] [--batches 1,2,4,...] [--frames 10]
      [--warmup 3] [--substeps 8] [--iterations 75] [--harmonic-every iteration|substep] [--profile] [--out table.md]
"""
from __future__ import annotations

import argparse
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import warp as wp

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from scenes.capsules import capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, make_motion
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning
from sim.xpbd import ClothSolver, FrameInputs, SolverSettings, harmonic_constraint

MAX_EDGE = 0.035  # pants: ~3.7k vertices low-res, ~14.5k after one level of Loop subdivision


def pants(n_frames: int):
    """Both levels of the pants, the attachment pins, per frame their targets and the capsules of the dance."""
    skel = default_skeleton()
    garment = make_garment("pants", skel, max_edge=MAX_EDGE)
    S, high_faces = loop_subdivide(garment.vertices, garment.faces, levels=1)
    state = body_state(skel, make_motion("dance", n_frames, settle_frames=0, blend_frames=10))
    a, b, ra, rb = capsules_world(skel, state.transforms)
    ids = garment.attachment  # the coarse vertices keep their ids after Loop subdivision
    targets = linear_blend_skinning(garment.vertices[ids], garment.attachment_part[:, None], np.ones((len(ids), 1)),
                                    rest_transforms(skel), state.transforms)
    levels = {"low": (garment.vertices, garment.faces), "high": (S @ garment.vertices, high_faces)}
    return levels, ids, targets, np.stack([a, b], axis=2), np.stack([ra[0], rb[0]], axis=1)


def harmonics(vertices, faces, pins):
    """The harmonic constraint of a high-res run (V/40 modes) and the target that holds the rest shape."""
    basis, _, mass = harmonic_basis(vertices, faces, harmonic_count(len(vertices)))
    return harmonic_constraint(basis, mass, pins), (mass[:, None] * basis).T @ vertices


def make_solver(vertices, faces, settings, device, pins, capsules, radii, worlds, harmonic):
    extra = {}
    if harmonic is not None:
        constraint, target = harmonic
        extra = dict(harmonic=constraint, harmonic_target=np.broadcast_to(target, (worlds, *target.shape)))
    return ClothSolver(vertices, faces, settings, device, pins, capsules=capsules[:worlds], capsule_radii=radii,
                       worlds=worlds, **extra), extra.get("harmonic_target")


def frame_inputs(f, worlds, targets, capsules, harmonic_target):
    shifted = np.arange(worlds) + f   # world w is w frames ahead in the dance
    return FrameInputs(pin_targets=targets[shifted], capsules=capsules[shifted], harmonic_target=harmonic_target)


def time_batch(solver, harmonic_target, targets, capsules, frames, warmup) -> float:
    times = []
    for f in range(1, warmup + frames + 1):
        inputs = frame_inputs(f, solver.worlds, targets, capsules, harmonic_target)
        start = time.perf_counter()
        solver.step(solver.state, inputs)
        solver.state.positions.numpy()  # what a stage stores each frame; also synchronises the device
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times[warmup:]))


def kernel_profile(solver, harmonic_target, targets, capsules) -> list[str]:
    """ms per kernel in one frame, launched eagerly (the graph hides its nodes from the timer)."""
    solver.step(solver.state, frame_inputs(1, solver.worlds, targets, capsules, harmonic_target))
    wp.synchronize()
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
    solver._launch_frame()
    wp.synchronize()
    totals, counts = defaultdict(float), defaultdict(int)
    for result in wp.timing_end():
        name = result.name.split("_", 1)[-1] if result.name.startswith("forward_") else result.name
        totals[name] += result.elapsed
        counts[name] += 1
    whole = sum(totals.values())
    return [f"| {name} | {counts[name]} | {ms:.2f} | {100 * ms / whole:.0f} % |"
            for name, ms in sorted(totals.items(), key=lambda kv: -kv[1])]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--levels", default="low,high")
    parser.add_argument("--batches", default="1,2,4,8,16,32,64,128")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=75)
    parser.add_argument("--harmonic-every", default="iteration", choices=("iteration", "substep"))
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--out")
    args = parser.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    levels, pins, targets, capsules, radii = pants(max(batches) + args.warmup + args.frames + 2)
    settings = SolverSettings(substeps=args.substeps, iterations=args.iterations, body_collision=True,
                              self_collision=True, harmonic_every=args.harmonic_every)
    rows = ["| level | V | B | ms per batch frame | cloth-frames/s | x B=1 |", "|---|---|---|---|---|---|"]
    profiles = []
    for level in args.levels.split(","):
        vertices, faces = levels[level]
        harmonic = harmonics(vertices, faces, pins) if level == "high" else None
        base = None
        for worlds in batches:
            solver, harmonic_target = make_solver(vertices, faces, settings, args.device, pins, capsules, radii,
                                                  worlds, harmonic)
            ms = time_batch(solver, harmonic_target, targets, capsules, args.frames, args.warmup)
            rate = worlds * 1e3 / ms
            base = base or rate
            rows.append(f"| {level} | {len(vertices)} | {worlds} | {ms:.2f} | {rate:.0f} | {rate / base:.1f} |")
            print(rows[-1], flush=True)
            if args.profile and worlds == batches[-1]:
                profiles += [f"\n{level}, B = {worlds}: one frame's kernels (eager launches)",
                             "| kernel | launches | ms | share |", "|---|---|---|---|",
                             *kernel_profile(solver, harmonic_target, targets, capsules)]
            del solver
    table = "\n".join(rows + profiles)
    print(f"\n{args.device}, {args.substeps} substeps x {args.iterations} iterations, body + self collision, harmonic "
          f"projection every {args.harmonic_every} (high), median "
          f"of {args.frames} frames after {args.warmup} warm-up frames\n{table}")
    if args.out:
        Path(args.out).write_text(table + "\n")


if __name__ == "__main__":
    main()
