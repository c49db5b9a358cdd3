"""The solvers' ms a frame as the trade-off stage measures them, in its own job beside the networks, so that a
speedup's two sides share the device, the process and its load: each low-res budget's run of one sequence and the
free high-res run of it (pipeline.solvers.xpbd's `free` level: the scene's physics, body and self collision where
it has them, not held to the low-res run: the paper's reference), each a solver world alone, stepped over every
frame of the sequence as the simulate stage steps it (the step and the read-back of the positions, synchronised),
the positions not kept."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from experiments.tradeoff.grid import point_simulation
from pipeline.artifacts.simulation import read_last_frame
from pipeline.core.config import simulation_settings
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import check_same_mesh
from pipeline.solvers.registry import solver_level
from sim.solver import UnstableSimulation


@dataclasses.dataclass(frozen=True)
class TimedSequence:
    """The sequence the solvers are timed on: its scene file, its low-res run at the scene's budget (where the
    high-res run starts: S x_low of frame 0) and, for a motion library's window, the scene's settle runs it starts
    from (results/<scene>/settle/sim_low.h5, sim_high.h5; None otherwise)."""
    scene: str
    sim_low: str
    settled_low: str | None = None
    settled_high: str | None = None


def solve_ms(settings: dict, level: str, group: tuple[str, ...], device: str, settled: str | None) -> np.ndarray:
    """ms of each frame after the first (which compiles kernels and captures the CUDA graph) of one sequence
    stepped alone at `level` with `settings` (a simulation.json's), the group's files as the simulate stage's."""
    batch = solver_level(settings, level, "--settings").prepare(
        settings, [group], device, True, 1, None if settled is None else _settled(settled, group[0]))
    solver = batch.solver
    times = []
    for f in range(1, batch.n_frames[0]):
        start = time.perf_counter()
        try:
            solver.step(solver.state, batch.inputs(f))
        except UnstableSimulation as err:
            raise PipelineError(f"{group[0]}: the {batch.label} run timed by the trade-off blew up ({err.cause}) "
                                f"at frame {f}") from None
        solver.state.read_world_positions()
        times.append((time.perf_counter() - start) * 1e3)
    if len(times) < 2:
        raise PipelineError(f"{group[0]}: {len(times) + 1} frame(s): the solver's timing needs at least 3")
    return np.asarray(times[1:])


def _settled(run: str, scene: str) -> np.ndarray:
    check_same_mesh(run, scene)
    return read_last_frame(run)


def low_res_ms(settings: dict, budget: tuple[int, int], sequence: TimedSequence, device: str) -> float:
    """Median ms a frame of the sequence's low-res run at `budget` (substeps, iterations; the scene's settings
    else)."""
    substeps, iterations = budget
    return float(np.median(solve_ms(point_simulation(settings, f"{substeps}x{iterations}"), "low",
                                    (sequence.scene,), device, sequence.settled_low)))


def free_high_res_ms(settings: dict, subdiv: str, sequence: TimedSequence, device: str) -> float:
    """Median ms a frame of the sequence's free high-res run at the scene's solver budget."""
    return float(np.median(solve_ms(simulation_settings(settings), "free",
                                    (sequence.scene, subdiv, sequence.sim_low), device, sequence.settled_high)))
