"""Agreement of the CPU and CUDA solvers: the same cloth run on both, positions compared frame by frame.

Reports max |x_cpu - x_cuda| relative to the cloth size after each checkpoint frame, for the patch and the flag
(low-res with a moving pin, and high-res with the harmonic constraint). Usage: python bench/cpu_vs_cuda.py
"""
from __future__ import annotations

import math

import numpy as np

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from scenes.grid import first_row_pins, grid_cloth
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, harmonic_constraint

CHECKPOINTS = (1, 10, 30, 60)


def run(vertices, faces, pins, device, harmonic, frames):
    target = None if harmonic is None else harmonic[1]
    model = ClothModel(vertices, faces, SolverSettings(), pins, harmonic=None if harmonic is None else harmonic[0])
    solver = ClothSolver(model, device, initial_inputs=FrameInputs(harmonic_target=target))
    out = {}
    for f in range(1, frames + 1):
        pin_targets = vertices[pins] + np.array([0.1, 0.0, 0.05]) * math.sin(f / 8)
        solver.step(solver.state, FrameInputs(pin_targets=pin_targets, harmonic_target=target))
        if f in CHECKPOINTS:
            out[f] = solver.state.read_positions()
    return out


def main():
    patch = grid_cloth(0.5, 0.5, 0.4, plane="xz", origin=(-0.25, 1.0, -0.25))
    flag = grid_cloth(1.0, 1.0, 0.12, plane="xy", origin=(-0.5, 1.5, 0.0))
    S, high_faces = loop_subdivide(*flag, levels=2)
    high = S @ flag[0]
    basis, _, mass = harmonic_basis(high, high_faces, harmonic_count(len(high)))
    high_pins = first_row_pins(high, "xy", "top_edge")
    # Hold the high-res run to the flag's rest low frequencies: a steady target, enough to exercise the projection.
    harmonic = (harmonic_constraint(basis, mass, high_pins), (mass[:, None] * basis).T @ high)
    cases = [("patch low", patch[0], patch[1], first_row_pins(patch[0], "xz", "corners"), None),
             ("flag low", flag[0], flag[1], first_row_pins(flag[0], "xy", "top_edge"), None),
             ("flag high+harmonic", high, high_faces, high_pins, harmonic)]
    print("| case | V | " + " | ".join(f"frame {f}" for f in CHECKPOINTS) + " |")
    print("|---|---|" + "---|" * len(CHECKPOINTS))
    for name, verts, faces, pins, harm in cases:
        cpu = run(verts, faces, pins, "cpu", harm, max(CHECKPOINTS))
        gpu = run(verts, faces, pins, "cuda:0", harm, max(CHECKPOINTS))
        size = np.ptp(verts, axis=0).max()
        errs = [np.abs(cpu[f] - gpu[f]).max() / size for f in CHECKPOINTS]
        print(f"| {name} | {len(verts)} | " + " | ".join(f"{e:.2e}" for e in errs) + " |")


if __name__ == "__main__":
    main()
