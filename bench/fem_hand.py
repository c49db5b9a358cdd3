"""The quasi-static FEM hand's cost per frame: the procedural hand at a size, driven along seeded random
joint-angle trajectories (one world each), each frame minimised to its residual tolerance.

Prints one table row per size: skin vertices, nodes, tets, worlds, the median wall time of a batched frame and
per hand-frame (the batch's over its worlds), the median Newton and CG iterations a frame, the share of frames
converged and the smallest tet volume ratio seen. The first frames (kernel compilation, the hand's first motion)
are left out. Usage: python bench/fem_hand.py [--device cuda:0] [--frames 40] [--worlds 1] [--sizes 0.008:0.008 ...]
(skin spacing:tet spacing, metres).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from geometry.tets import tet_volumes
from scenes.hand_motion import random_trajectory
from scenes.hand_shape import procedural_hand
from scenes.hand_skeleton import hand_transforms
from sim.fem import FemInputs, FemModel, FemSettings, FemSolver

WARMUP = 3
FPS = 30.0


def bench(skin: float, tet: float, device: str, frames: int, worlds: int) -> str:
    hand = procedural_hand(skin, tet)
    vol = hand.volume
    model = FemModel(vol.nodes, vol.tets, FemSettings(), vol.driven, vol.embedding)
    solver = FemSolver(model, device, worlds=worlds)
    angles = np.stack([random_trajectory(frames + 1, FPS, seed) for seed in range(worlds)], 1)   # (F, B, 18)
    transforms = hand_transforms(hand.skeleton, angles)
    rest_volume = tet_volumes(vol.nodes, vol.tets)
    times, newton, cg, converged, least = [], [], [], [], np.inf
    for f in range(1, frames + 1):
        now = (transforms[0][f], transforms[1][f])
        last = (transforms[0][f - 1], transforms[1][f - 1])
        inputs = FemInputs(hand.driven_targets(now), hand.node_motion(last, now))
        start = time.perf_counter()
        solver.step(solver.state, inputs)
        solver.state.read_world_positions()                       # what the stage stores, synchronising too
        elapsed = time.perf_counter() - start
        report = solver.last_report
        if f > WARMUP:
            times.append(elapsed)
            newton.append(report.newton_iterations.max())
            cg.append(report.cg_iterations)
            converged.append(report.converged.mean())
        nodes = solver.state.read_nodes()
        least = min(least, min((tet_volumes(x, vol.tets) / rest_volume).min() for x in nodes))
    ms = 1e3 * float(np.median(times))
    return (f"| {skin}:{tet} | {len(hand.skin_vertices):,} | {len(vol.nodes):,} | {len(vol.tets):,} | {worlds} | "
            f"{ms:,.0f} | {ms / worlds:,.1f} | {np.median(newton):.0f} | {np.median(cg):.0f} | "
            f"{100 * np.mean(converged):.0f}% | {least:.2f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--worlds", type=int, default=1)
    parser.add_argument("--sizes", nargs="+", default=["0.008:0.008", "0.006:0.006"])
    args = parser.parse_args()
    print(f"device {args.device}, {args.frames} frames at {FPS:.0f} fps (the first {WARMUP} left out)")
    print("| skin:tet spacing (m) | skin vertices | nodes | tets | worlds | ms / batched frame | ms / hand-frame | "
          "Newton / frame | CG / frame | converged | least volume ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes:
        skin, tet = (float(v) for v in size.split(":"))
        print(bench(skin, tet, args.device, args.frames, args.worlds), flush=True)


if __name__ == "__main__":
    main()
