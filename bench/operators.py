"""Operator precompute speed: all four convolution kinds at L = 13 and 10 pooling steps on ~15k-vertex meshes, on
one CPU core (issue #3 budget: 60 s), plus the choice of assignment solver for the many tiny RC/EC problems.

Meshes: `flag` is the flag scene's high-res mesh (grid cloth, max edge 0.046, Loop-subdivided twice), `pants` a
stretched sphere with three holes cut, `sphere` a closed cube-sphere. The process restarts itself pinned to one
core with one BLAS thread; CPU time next to wall time shows how much other processes on that core slowed a run
(the per-part columns are wall time). Usage:
  python bench/operators.py [--meshes flag,pants,sphere] [--repeat 1] [--problems 20000] [--out table.md]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import lap
import numpy as np
from scipy.optimize import linear_sum_assignment

from geometry.shapes import cube_sphere, pants
from meshops import build_operators
from scenes.flag_mesh import flag_high_res

ONE_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
PARTS = ("neighbourhood", "RC13", "EC13", "SP13", "SPD13", "pooling")


MESHES = {"flag": lambda: flag_high_res(0.046), "pants": lambda: pants(55), "sphere": lambda: cube_sphere(50)}


def time_operators(name: str, repeat: int) -> list[str]:
    vertices, faces = MESHES[name]()
    runs = []
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        levels = build_operators(vertices, faces)
        runs.append((time.perf_counter() - wall, time.process_time() - cpu, levels))
    wall, cpu, levels = min(runs, key=lambda run: run[0])
    parts = {part: sum(level.seconds.get(part, 0.0) for level in levels) for part in PARTS}
    counts = [len(level.vertices) for level in levels]
    fallbacks = sum(level.ec_fallbacks["EC13"] for level in levels)
    return [f"| {name} | {len(vertices)} | {wall:.1f} | {cpu:.1f} | " + " | ".join(f"{parts[p]:.2f}" for p in PARTS)
            + f" | {'/'.join(map(str, counts))} | {fallbacks} |"]


def assignment_problems(count: int, seed: int = 0) -> list[np.ndarray]:
    """Cost blocks shaped like RC13's: 12 samples x ~37 candidates (1-3-ring of a valence-6 vertex), integer
    costs in 1e-6 edge lengths, and the lexicographic penalty on the 30 candidates beyond the one-ring."""
    rng = np.random.default_rng(seed)
    problems = []
    for _ in range(count):
        candidates = rng.integers(30, 45)
        cost = np.rint(rng.uniform(0.0, 3.0, (12, candidates)) * 1e6)
        cost[:, 6:] += 12 * cost.max() + 1
        problems.append(cost)
    return problems


def time_solvers(count: int) -> list[str]:
    problems = assignment_problems(count)
    started = time.perf_counter()
    scipy_totals = [c[linear_sum_assignment(c)].sum() for c in problems]
    scipy_seconds = time.perf_counter() - started
    started = time.perf_counter()
    lap_totals = [c[np.arange(12), lap.lapjv(c, extend_cost=True, return_cost=False)[0]].sum() for c in problems]
    lap_seconds = time.perf_counter() - started
    worse = sum(b > a + 0.5 for a, b in zip(scipy_totals, lap_totals))
    return [f"| scipy.optimize.linear_sum_assignment | {scipy_seconds / count * 1e6:.1f} | reference |",
            f"| lap.lapjv(extend_cost=True) | {lap_seconds / count * 1e6:.1f} | "
            f"{worse} of {count} above the optimum |"]


def run_on_one_core() -> None:
    """Restart this process pinned to one core with one BLAS thread, unless it already is: BLAS reads its thread
    count once, when numpy loads, so the variables must be set before the imports above run."""
    if all(os.environ.get(name) == "1" for name in ONE_THREAD) and len(os.sched_getaffinity(0)) == 1:
        return
    os.environ.update({name: "1" for name in ONE_THREAD})
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    os.execv(sys.executable, [sys.executable, *sys.argv])


def main() -> None:
    run_on_one_core()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", default=",".join(MESHES))
    parser.add_argument("--repeat", type=int, default=1, help="runs per mesh; the fastest (wall time) is reported")
    parser.add_argument("--problems", type=int, default=20000, help="assignment problems for the solver timing")
    parser.add_argument("--out", help="also write the tables to this markdown file")
    args = parser.parse_args()

    lines = ["| mesh | vertices | wall s | CPU s | " + " | ".join(f"{p} s" for p in PARTS) + " | vertices per level "
             "| EC fallbacks |", "|" + " --- |" * (len(PARTS) + 6)]
    for name in args.meshes.split(","):
        lines += time_operators(name, args.repeat)
        print(lines[-1], flush=True)
    lines += ["", "| solver (12 x 30-44 costs) | us per problem | result |", "| --- | --- | --- |"]
    lines += time_solvers(args.problems)
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
