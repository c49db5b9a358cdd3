"""Solver speed: ms per frame for low- and high-res cloth, CPU and CUDA, at the paper's 8 substeps x 75 iterations.

Median over measured frames after warm-up frames (the first frame compiles kernels and, on CUDA, captures the frame
graph). Each row's ratio is against the first variant of the same mesh and device in the same invocation: for the
flags the stretch-only run, so the price of bending and of the harmonic constraint is visible; for the garments
(`pants`, `tshirt`: a low-res garment and its Loop subdivision, worn by the mannequin dancing) the stretch-only run
too, then the price of bending ("no collision"), of the body and of self-collision. `--lanes 1,4` times each
CUDA run with those threads per vertex in the sweeps (ClothSolver's sweep_lanes; default: the solver's).
`--frame-kernels sweeps,block` times each run with each way of launching a frame (settings.frame_kernel: a kernel
per sweep, or the whole frame in one launch of a block per world where the cloth fits, sim/xpbd/block_frame.py;
default: the simulate stage's, SolverSettings' frame_kernel); each row names the one that ran, its
cloth-frames/s and its speed over the sweeps of the same variant. `--block-layouts 1024,128x8x4` times the block
frame with each of those layouts (threads a block x blocks a world, a cluster x lanes a vertex:
block_frame.BlockLayout; default: the solver's). `--variants body+self` times the garments' variants named only
(default: all four). `pants-paper` is the paper profile's low-res pants (max_edge 0.08,
757 vertices).
Usage:
  python bench/cloth_solver.py [--devices cpu,cuda:0] [--cases flag,15k,pants,pants-paper,tshirt] [--frames 10]
  [--warmup 3] [--substeps 8] [--iterations 75] [--lanes 1,4] [--frame-kernels sweeps,block]
  [--block-layouts 1024,128x8x4] [--variants body+self] [--out table.md]
e.g. the collision cases on a GPU: python bench/cloth_solver.py --devices cuda:0 --cases pants,tshirt
and the one-block frame against the sweeps: python bench/cloth_solver.py --devices cuda:0 --cases pants-paper
  --frame-kernels sweeps,block --skip-high
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import warp as wp

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from scenes.capsules import capsules_world
from scenes.garments import make_garment
from scenes.grid import first_row_pins, grid_cloth
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, make_motion
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, harmonic_constraint
from sim.xpbd.solver import frame_kernel_of
from sim.xpbd.block_frame import BlockLayout

# Low-res grids: the flag of the CPU profile, the paper-sized flag, and one whose high-res mesh has ~15k vertices.
CASES = {"flag-cpu": 0.12, "flag": 0.08, "15k": 0.046}
# Garment and max_edge: ~3.5k vertices low-res, ~14k after one level of Loop subdivision; the paper profile's pants.
GARMENTS = {"pants": ("pants", 0.035), "tshirt": ("tshirt", 0.03), "pants-paper": ("pants", 0.08)}


def build(max_edge: float):
    low, low_faces = grid_cloth(1.0, 1.0, max_edge, plane="xy", origin=(-0.5, 1.5, 0.0))
    S, faces = loop_subdivide(low, low_faces, levels=2)
    high = S @ low
    return (low, low_faces), (high, faces)


def time_run(vertices, faces, settings, device, pins, frames, warmup, lanes, layout, harmonic=None):
    target = None
    if harmonic is not None:
        constraint, basis, mass = harmonic
        target = (mass[:, None] * basis).T @ vertices
    model = ClothModel(vertices, faces, settings, pins, harmonic=harmonic and harmonic[0])
    solver = ClothSolver(model, device, initial_inputs=FrameInputs(harmonic_target=target), sweep_lanes=lanes,
                         block_layout=layout)
    sway = np.array([0.05, 0.0, 0.03])
    times = []
    for f in range(warmup + frames):
        pin_targets = vertices[pins] + sway * math.sin(f / 10)
        start = time.perf_counter()
        solver.step(solver.state, FrameInputs(pin_targets=pin_targets, harmonic_target=target))
        solver.state.positions.numpy()  # the positions a stage stores each frame; also synchronises the device
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times[warmup:])), solver


def garment_inputs(kind: str, n_frames: int):
    """The garment (low-res and one Loop level finer), its pinned attachment vertices and, per frame, their targets
    and the capsules of the mannequin dancing (no settling: the dance fades in over the first 10 frames)."""
    skel = default_skeleton()
    name, max_edge = GARMENTS[kind]
    garment = make_garment(name, skel, max_edge=max_edge)
    S, high_faces = loop_subdivide(garment.vertices, garment.faces, levels=1)
    state = body_state(skel, make_motion("dance", n_frames, settle_frames=0, blend_frames=10))
    a, b, ra, rb = capsules_world(skel, state.transforms)
    capsules, radii = np.stack([a, b], axis=2), np.stack([ra[0], rb[0]], axis=1)
    ids = garment.attachment  # Loop subdivision keeps the coarse vertices first, so the ids hold on both levels
    targets = linear_blend_skinning(garment.vertices[ids], garment.attachment_part[:, None], np.ones((len(ids), 1)),
                                    rest_transforms(skel), state.transforms)
    levels = {"low": (garment.vertices, garment.faces), "high": (S @ garment.vertices, high_faces)}
    return levels, ids, targets, capsules, radii


def time_garment(model, device, targets, capsules, frames, warmup, lanes, layout):
    body = model.settings.body_collision
    solver = ClothSolver(model, device, initial_inputs=FrameInputs(capsules=capsules[0] if body else None),
                         sweep_lanes=lanes, block_layout=layout)
    times = []
    for f in range(1, warmup + frames + 1):
        start = time.perf_counter()
        solver.step(solver.state, FrameInputs(pin_targets=targets[f], capsules=capsules[f] if body else None))
        solver.state.positions.numpy()
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times[warmup:])), solver


# A garment's variants in turn, each adding to the one before: their names are --variants' values.
GARMENT_VARIANTS = {"stretch only": dict(bending=False), "no collision": {}, "body": dict(body_collision=True),
                    "body+self": dict(body_collision=True, self_collision=True)}


def garment_rows(case: str, args) -> list[str]:
    levels, pins, targets, capsules, radii = garment_inputs(case, args.warmup + args.frames + 1)
    rows = []
    for device in args.devices.split(","):
        for level, (verts, faces) in levels.items():
            if skipped(level, device, args):
                continue
            base = dict(substeps=args.substeps, iterations=args.iterations)
            baseline = None
            for name, switches in GARMENT_VARIANTS.items():
                if name not in args.variants.split(","):
                    continue
                sweeps_ms = None
                for lanes, kernel, layout in run_variants(device, args):
                    settings = SolverSettings(**base, **switches, frame_kernel=kernel)
                    model = ClothModel(verts, faces, settings, pins,
                                       capsule_radii=radii if settings.body_collision else None)
                    if kernel != "auto" and frame_kernel_of(model, wp.get_device(device)) != kernel:
                        continue   # the cloth does not fit a block
                    ms, solver = time_garment(model, device, targets, capsules, args.frames, args.warmup, lanes,
                                              layout)
                    baseline = baseline or ms
                    sweeps_ms = ms if solver.frame_kernel == "sweeps" else sweeps_ms
                    rows.append(row(case, level, len(verts), "-", device, solver, name, ms, baseline, sweeps_ms))
                    print(rows[-1], flush=True)
    return rows


def row(case, level, vertices, k, device, solver, name, ms, baseline, sweeps_ms) -> str:
    """A table row: how the frame was launched, ms a frame, cloth-frames/s (one cloth), the ratio to the mesh's
    first row and the speed over the sweeps of the same variant (when timed before it)."""
    over_sweeps = f"{sweeps_ms / ms:.2f}" if sweeps_ms else "-"
    return (f"| {case} | {level} | {vertices} | {k} | {device} | {solver.launch_summary()} | {name} | "
            f"{ms:.2f} | {1e3 / ms:.0f} | {ms / baseline:.2f} | {over_sweeps} |")


def skipped(level: str, device: str, args) -> bool:
    return level == "high" and (args.skip_high or (device == "cpu" and args.skip_cpu_high))


def flag_rows(case: str, args) -> list[str]:
    (low, low_faces), (high, high_faces) = build(CASES[case])
    k = harmonic_count(len(high))
    t0 = time.perf_counter()
    basis, _, mass = harmonic_basis(high, high_faces, k)
    print(f"{case}: {len(low)} low / {len(high)} high vertices, K={k}, eigensolve {time.perf_counter() - t0:.1f} s",
          flush=True)
    rows = []
    for device in args.devices.split(","):
        for level, (verts, faces) in (("low", (low, low_faces)), ("high", (high, high_faces))):
            if skipped(level, device, args):
                continue
            pins = first_row_pins(verts, "xy", "top_edge")
            base = dict(substeps=args.substeps, iterations=args.iterations)
            variants = [("stretch only", SolverSettings(**base, bending=False), None),
                        ("stretch+bending", SolverSettings(**base), None)]
            if level == "high":
                variants.append(("+harmonic each iteration", SolverSettings(**base),
                                 (harmonic_constraint(basis, mass, pins), basis, mass)))
            baseline = None
            for name, settings, harmonic in variants:
                sweeps_ms = None
                for lanes, kernel, layout in run_variants(device, args):
                    variant = dataclasses.replace(settings, frame_kernel=kernel)
                    if kernel != "auto" and frame_kernel_of(ClothModel(verts, faces, variant, pins,
                                                                       harmonic=harmonic and harmonic[0]),
                                                            wp.get_device(device)) != kernel:
                        continue   # the cloth does not fit a block
                    ms, solver = time_run(verts, faces, variant, device, pins, args.frames, args.warmup, lanes, layout,
                                          harmonic)
                    baseline = baseline or ms
                    sweeps_ms = ms if solver.frame_kernel == "sweeps" else sweeps_ms
                    rows.append(row(case, level, len(verts), k if harmonic else "-", device, solver, name, ms,
                                    baseline, sweeps_ms))
                    print(rows[-1], flush=True)
    return rows


def run_variants(device: str, args) -> list[tuple[int | None, str, BlockLayout | None]]:
    """The (sweep_lanes, frame_kernel, block_layout) to time on `device`: each of --lanes (None: the solver's
    default; the CPU takes 1 only) with each of --frame-kernels but the block frame, which takes each of
    --block-layouts (None: the solver's default) instead."""
    lanes = [int(n) for n in args.lanes.split(",")] if args.lanes and device.startswith("cuda") else [None]
    layouts = [BlockLayout.from_text(t) for t in args.block_layouts.split(",")] if args.block_layouts else [None]
    return [(n, kernel, layout) for kernel in args.frame_kernels.split(",")
            for n in (lanes if kernel != "block" else [None])
            for layout in (layouts if kernel == "block" else [None])]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", default="cpu")
    parser.add_argument("--cases", default="flag-cpu,flag,15k")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=75)
    parser.add_argument("--skip-cpu-high", action="store_true", help="skip high-res runs on the CPU (slow)")
    parser.add_argument("--skip-high", action="store_true", help="skip high-res runs on every device")
    parser.add_argument("--lanes", default="", help="CUDA threads per vertex in the sweeps, e.g. 1,4")
    # The simulate stage's way by default: an unqualified run timed the one-block frame (slower on an H100:
    # docs/performance.md), where a user reads the stage's speed.
    parser.add_argument("--frame-kernels", default=SolverSettings().frame_kernel,
                        help="ways to launch a frame, e.g. sweeps,block (default: the solver's)")
    parser.add_argument("--block-layouts", default="",
                        help="the block frame's layouts, THREADSxCLUSTER_BLOCKSxLANES, e.g. 1024,128x8x4")
    parser.add_argument("--variants", default=",".join(GARMENT_VARIANTS),
                        help=f"the garments' variants to time, of {','.join(GARMENT_VARIANTS)} (default: all)")
    parser.add_argument("--out", help="also write the table here")
    args = parser.parse_args()
    unknown = set(args.variants.split(",")) - set(GARMENT_VARIANTS)
    if unknown:
        parser.error(f"--variants: unknown {', '.join(sorted(unknown))}; choose from {','.join(GARMENT_VARIANTS)}")
    rows = ["| mesh | level | V | K | device | launch | variant | ms/frame | cloth-frames/s | x first row | "
            "speed over sweeps |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case in args.cases.split(","):
        rows += garment_rows(case, args) if case in GARMENTS else flag_rows(case, args)
    table = "\n".join(rows)
    print(f"\n{args.substeps} substeps x {args.iterations} iterations, median of {args.frames} frames after "
          f"{args.warmup} warm-up frames\n{table}")
    if args.out:
        Path(args.out).write_text(table + "\n")


if __name__ == "__main__":
    main()
