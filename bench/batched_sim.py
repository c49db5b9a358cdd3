"""Batched simulation throughput: cloth-frames per second against the number of worlds B stepped together.

Pants worn by the mannequin, low-res (~3.7k vertices; `--max-edge 0.08`: the paper profile's 757) and one Loop level
finer (~14.5k), body + self collision, the paper's 8 substeps x 75 iterations; world w plays motion kind w mod 4
(dance, karate, random, walk) with seed w, fading in from the rest pose over 10 frames (each world its own body
motion and pins, all starting where the garment was made, as a sequence of the stage does); the high-res rows hold
every world to its own low-res run (stepped first) by the harmonic constraint (V/40 modes), as the simulate stage
does.
Per B: median ms per batch frame over measured frames after warm-up (the first frames compile and capture the
graph), cloth-frames/s = B * 1000 / ms, and the ratio to B = 1 in the same run. `--profile` adds where one frame's
time goes, per kernel, at the largest B (CUDA only; launched without the graph, so each kernel is timed on its
own). `--contacts` adds the low-res batches with body and self collision each switched off (what the contacts
cost). `--peer newton` adds, per level and B, the same cloth hanging from its pins without body or contact, stepped
by this solver and by NVIDIA Newton's XPBD in the same run (bench/newton_peer.py; one line instead where Newton is
not installed). `--lanes 1,4` times each B with those threads per vertex in the sweeps (ClothSolver's
sweep_lanes; default: the solver's). `--frame-kernels sweeps,block` times each B with each way of launching a
frame (settings.frame_kernel: a kernel per sweep, or the frame in one launch of a block per world where the cloth
fits, sim/xpbd/block_frame.py: the low-res pants; default: the simulate stage's, SolverSettings' frame_kernel,
so that an unqualified run times what the stage runs); each row names the one
that ran and its speed over the sweeps of the same B; `--block-layouts 1024,128x8x4` times the block frame with
those layouts (threads a block x blocks a world, a cluster x lanes a vertex: block_frame.BlockLayout; default: the
solver's). Usage:
  python bench/batched_sim.py [--device cuda:0] [--levels low,high] [--batches 1,2,4,...] [--frames 10]
      [--warmup 3] [--substeps 8] [--iterations 75] [--harmonic-every substep|iteration] [--profile]
      [--contacts] [--peer newton] [--lanes 1,4] [--frame-kernels sweeps,block]
      [--block-layouts 1024,128x8x4] [--max-edge 0.08] [--out table.md]
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import warp as wp

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from newton_peer import newton_hanging, newton_missing, ours_hanging  # bench/ is the script's own folder
from pipeline.solvers.harmonic_targets import BasisProducts, harmonic_targets_of
from scenes.capsules import capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, make_motion
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, harmonic_constraint
from sim.xpbd.clearance import SubdividedOutsideBody
from sim.xpbd.block_frame import BlockLayout
from sim.xpbd.solver import frame_kernel_of

MAX_EDGE = 0.035  # pants: ~3.7k vertices low-res, ~14.5k after one level of Loop subdivision


KINDS = ("dance", "karate", "random", "walk")


def pants(n_frames: int, worlds: int, max_edge: float = MAX_EDGE):
    """Both levels of the pants, the attachment pins and, per world and frame, their targets (W, F, P, 3) and the
    capsules (W, F, N, 2, 3) of the world's motion."""
    skel = default_skeleton()
    garment = make_garment("pants", skel, max_edge=max_edge)
    S, high_faces = loop_subdivide(garment.vertices, garment.faces, levels=1)
    ids = garment.attachment  # the coarse vertices keep their ids after Loop subdivision
    targets, capsules = [], []
    for w in range(worlds):
        motion = make_motion(KINDS[w % len(KINDS)], n_frames, seed=w, settle_frames=0, blend_frames=10)
        state = body_state(skel, motion)
        a, b, ra, rb = capsules_world(skel, state.transforms)
        targets.append(linear_blend_skinning(garment.vertices[ids], garment.attachment_part[:, None],
                                             np.ones((len(ids), 1)), rest_transforms(skel), state.transforms))
        capsules.append(np.stack([a, b], axis=2))
    levels = {"low": (garment.vertices, garment.faces), "high": (S @ garment.vertices, high_faces)}
    return levels, ids, np.stack(targets), np.stack(capsules), np.stack([ra[0], rb[0]], axis=1)


def harmonics(vertices, faces, pins):
    """The harmonic constraint of a high-res run (V/40 modes)."""
    basis, _, mass = harmonic_basis(vertices, faces, harmonic_count(len(vertices)))
    return harmonic_constraint(basis, mass, pins)


def harmonic_targets(constraint, S, x_low, capsules, radii, settings, device):
    """B^T M S x_low (F, B, K, 3) of low-res positions (F, B, V_low, 3), S x_low moved clear of each world's
    capsules (B, F', P, 2, 3) first: the simulate stage's own path (pipeline.solvers.xpbd.prepare_high)."""
    products = BasisProducts(constraint.mass_basis.T, S)
    clear = SubdividedOutsideBody(S, radii, settings.collision_thickness, device)
    f = x_low.shape[0]
    return np.stack([harmonic_targets_of(x_low[:, w], products, clear(x_low[:, w], capsules[w, :f]))
                     for w in range(x_low.shape[1])], axis=1)


def low_res_run(low, settings, device, pins, targets, capsules, radii, worlds, n_frames):
    """(F, B, V_low, 3) positions of the worlds' low-res runs, frame 0 the rest state."""
    solver = ClothSolver(ClothModel(*low, settings, pins, capsule_radii=radii), device, worlds=worlds,
                         initial_inputs=FrameInputs(capsules=capsules[:worlds, 0]))
    frames = [solver.state.read_world_positions().astype(np.float64)]
    for f in range(1, n_frames):
        solver.step(solver.state, frame_inputs(f, worlds, targets, capsules, None))
        frames.append(solver.state.read_world_positions().astype(np.float64))
    return np.stack(frames)


def make_solver(vertices, faces, settings, device, pins, capsules, radii, worlds, constraint, goals, start,
                lanes=None, block_layout=None):
    """The solver of a batch of `worlds` (with the harmonic constraint: starting at `start`, held to `goals`)."""
    body = settings.body_collision
    model = ClothModel(vertices, faces, settings, pins, harmonic=constraint, capsule_radii=radii if body else None)
    inputs = FrameInputs(harmonic_target=None if constraint is None else goals[0],
                         capsules=capsules[:worlds, 0] if body else None)
    return ClothSolver(model, device, worlds=worlds, initial_inputs=inputs, initial_positions=start, sweep_lanes=lanes,
                       block_layout=block_layout)


def frame_inputs(f, worlds, targets, capsules, goals, body=True):
    return FrameInputs(pin_targets=targets[:worlds, f], capsules=capsules[:worlds, f] if body else None,
                       harmonic_target=None if goals is None else goals[f])


def time_batch(solver, harmonic_target, targets, capsules, frames, warmup) -> float:
    times = []
    for f in range(1, warmup + frames + 1):
        inputs = frame_inputs(f, solver.worlds, targets, capsules, harmonic_target,
                              solver.model.settings.body_collision)
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


def contact_rows(levels, pins, targets, capsules, radii, batches, settings, args) -> list[str]:
    """The low-res batch with body and self collision each switched off: what the contacts cost."""
    rows = ["\nLow-res, contacts switched off (ms per batch frame)", "| B | body + self | body only | self only | "
            "neither |", "|---|---|---|---|---|"]
    for worlds in batches:
        cells = []
        for body, self_contact in ((True, True), (True, False), (False, True), (False, False)):
            variant = dataclasses.replace(settings, body_collision=body, self_collision=self_contact)
            solver = make_solver(*levels["low"], variant, args.device, pins, capsules, radii, worlds, None, None, None)
            cells.append(f"{time_batch(solver, None, targets, capsules, args.frames, args.warmup):.2f}")
        rows.append(f"| {worlds} | {' | '.join(cells)} |")
        print(rows[-1], flush=True)
    return rows


def peer_rows(levels, pins, batches, settings, args) -> list[str]:
    """The hanging-cloth comparison with Newton (bench/newton_peer.py), as table lines."""
    missing = newton_missing()
    if missing:
        print(f"peer: skipped: {missing}", flush=True)
        return [f"\npeer: skipped: {missing}"]
    rows = ["\nHanging from the pins, no body, no contact, this solver against Newton's XPBD (same mesh, pins, "
            "budget; stretch: largest edge length / rest at the end)",
            "| level | V | B | ours ms | Newton ms | ours cloth-frames/s | Newton cloth-frames/s | ours / Newton speed "
            "| ours stretch | Newton stretch |", "|---|---|---|---|---|---|---|---|---|---|"]
    for level in args.levels.split(","):
        vertices, faces = levels[level]
        for worlds in batches:
            ours, peer = (run(vertices, faces, pins, worlds, settings, args.device, args.frames, args.warmup)
                          for run in (ours_hanging, newton_hanging))
            rows.append(f"| {level} | {len(vertices)} | {worlds} | {ours.ms:.2f} | {peer.ms:.2f} | "
                        f"{worlds * 1e3 / ours.ms:.0f} | {worlds * 1e3 / peer.ms:.0f} | {peer.ms / ours.ms:.2f} | "
                        f"{ours.stretch:.3f} | {peer.stretch:.3f} |")
            print(rows[-1], flush=True)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--levels", default="low,high")
    parser.add_argument("--batches", default="1,2,4,8,16,32,64,128,256")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=75)
    parser.add_argument("--harmonic-every", default="substep", choices=("iteration", "substep"),
                        help="the simulate stage's default, high_res.harmonic_every, is substep")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--peer", choices=("newton",), help="also time NVIDIA Newton's XPBD on the hanging cloth")
    parser.add_argument("--contacts", action="store_true", help="also time the low-res batches with body and self "
                        "collision switched off")
    parser.add_argument("--lanes", default="", help="threads per vertex in the sweeps, e.g. 1,4")
    parser.add_argument("--frame-kernels", default=SolverSettings().frame_kernel,
                        help="ways to launch a frame, e.g. sweeps,block,auto")
    parser.add_argument("--block-layouts", default="",
                        help="the block frame's layouts, THREADSxCLUSTER_BLOCKSxLANES, e.g. 1024,128x8x4")
    parser.add_argument("--max-edge", type=float, default=MAX_EDGE,
                        help="the pants' longest low-res edge: 0.08 is the paper profile's (757 vertices)")
    parser.add_argument("--out")
    args = parser.parse_args()
    batches = [int(b) for b in args.batches.split(",")]
    n_frames = args.warmup + args.frames + 2
    levels, pins, targets, capsules, radii = pants(n_frames, max(batches), args.max_edge)
    S, _ = loop_subdivide(*levels["low"], levels=1)
    settings = SolverSettings(substeps=args.substeps, iterations=args.iterations, body_collision=True,
                              self_collision=True, harmonic_every=args.harmonic_every)
    lane_counts = [int(lanes) for lanes in args.lanes.split(",")] if args.lanes else [None]
    # (lanes, frame kernel, block layout): lanes are the sweeps' threads a vertex, the layout the block frame's.
    layouts = [BlockLayout.from_text(t) for t in args.block_layouts.split(",")] if args.block_layouts else [None]
    variants = [(lanes, kernel, layout) for kernel in args.frame_kernels.split(",")
                for lanes in (lane_counts if kernel != "block" else [None])
                for layout in (layouts if kernel == "block" else [None])]
    rows = ["| level | V | B | launch | ms per batch frame | cloth-frames/s | x first row | speed over sweeps |",
            "|---|---|---|---|---|---|---|---|"]
    profiles = []
    for level in args.levels.split(","):
        vertices, faces = levels[level]
        constraint = harmonics(vertices, faces, pins) if level == "high" else None
        base = None
        for worlds in batches:
            goals = start = None
            if constraint is not None:
                x_low = low_res_run(levels["low"], settings, args.device, pins, targets, capsules, radii, worlds,
                                    n_frames)
                goals = harmonic_targets(constraint, S, x_low, capsules, radii, settings, args.device)
                start = np.stack([S @ x for x in x_low[0]])
            sweeps_ms = None
            for lanes, kernel, layout in variants:
                variant = dataclasses.replace(settings, frame_kernel=kernel)
                model_fits = kernel != "block" or frame_kernel_of(ClothModel(vertices, faces, variant, pins,
                                                                             capsule_radii=radii,
                                                                             harmonic=constraint),
                                                                  wp.get_device(args.device)) == "block"
                if not model_fits:
                    continue   # the cloth does not fit a block
                solver = make_solver(vertices, faces, variant, args.device, pins, capsules, radii, worlds, constraint,
                                     goals, start, lanes, layout)
                ms = time_batch(solver, goals, targets, capsules, args.frames, args.warmup)
                rate = worlds * 1e3 / ms
                base = base or rate
                sweeps_ms = ms if solver.frame_kernel == "sweeps" else sweeps_ms
                rows.append(f"| {level} | {len(vertices)} | {worlds} | {solver.launch_summary()} | {ms:.2f} | "
                            f"{rate:.0f} | {rate / base:.1f} | {f'{sweeps_ms / ms:.2f}' if sweeps_ms else '-'} |")
                print(rows[-1], flush=True)
                if args.profile and worlds == batches[-1]:
                    profiles += [f"\n{level}, B = {worlds}, {solver.launch_summary()}: one frame's kernels (eager "
                                 "launches)", "| kernel | launches | ms | share |", "|---|---|---|---|",
                                 *kernel_profile(solver, goals, targets, capsules)]
                del solver
    peers = peer_rows(levels, pins, batches, settings, args) if args.peer else []
    contacts = contact_rows(levels, pins, targets, capsules, radii, batches, settings, args) if args.contacts else []
    table = "\n".join(rows + profiles + contacts + peers)
    print(f"\n{args.device}, {args.substeps} substeps x {args.iterations} iterations, body + self collision, harmonic "
          f"projection every {args.harmonic_every} (high), median "
          f"of {args.frames} frames after {args.warmup} warm-up frames\n{table}")
    if args.out:
        Path(args.out).write_text(table + "\n")


if __name__ == "__main__":
    main()
