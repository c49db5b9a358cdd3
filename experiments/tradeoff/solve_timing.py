"""The solvers' ms a frame as the trade-off stage measures them, in its own job beside the networks, so that a
speedup's two sides share the device, the process and its load: each low-res budget's run of one sequence and the
free high-res run of it (pipeline.solvers.xpbd's `free` level: the scene's physics, body and self collision where
it has them, not held to the low-res run: the paper's reference), each a solver world alone, stepped over every
frame of the sequence as the simulate stage steps it (the step and the read-back of the positions, synchronised),
the positions not kept. Where the scene's two frame kernels step the low-res cloth differently on the device (the
sweeps and, on a GPU with thread block clusters, the cluster frame), a budget is timed with each and the faster
kept: which one wins depends on the budget (docs/performance.md, "One launch a frame")."""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import warp as wp

from experiments.tradeoff.grid import point_simulation
from pipeline.artifacts.scene import read_rest_mesh
from pipeline.artifacts.simulation import read_last_frame
from pipeline.core.config import simulation_settings
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import check_same_mesh
from pipeline.solvers.registry import solver_level
from pipeline.solvers.xpbd import solver_settings
from sim.solver import UnstableSimulation
from sim.xpbd.settings import SolverSettings
from sim.xpbd.solver import frame_kernel_for


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


@dataclasses.dataclass(frozen=True)
class LowResMs:
    """A low-res budget's median ms a frame, the frame kernel that stepped it ("sweeps" or "block":
    sim.xpbd.solver.frame_kernel_for) and the other kernel's median where both were timed (NaN otherwise)."""
    ms: float
    frame_kernel: str
    other_ms: float = np.nan


def kernels_to_time(solver: SolverSettings, device: wp.Device, vertices: int, harmonic: bool) -> tuple[str, ...]:
    """The frame kernels to time a cloth of `vertices` (with the harmonic constraint or not) with on `device`: both
    where "sweeps" and "auto" step it differently (the faster is kept), else the one the scene's
    `solver.frame_kernel` steps it with, once."""
    both = tuple(frame_kernel_for(wanted, vertices, harmonic, device) for wanted in ("sweeps", "auto"))
    return both if both[0] != both[1] else (frame_kernel_for(solver.frame_kernel, vertices, harmonic, device),)


def faster_kernel(medians: dict[str, float]) -> LowResMs:
    """The kernel of the least median ms (kernel -> median of one or two kernels), beside the other's."""
    fastest = min(medians, key=medians.get)
    others = [ms for kernel, ms in medians.items() if kernel != fastest]
    return LowResMs(medians[fastest], fastest, others[0] if others else np.nan)


def low_res_ms(settings: dict, budget: tuple[int, int], sequence: TimedSequence, device: str) -> LowResMs:
    """Median ms a frame of the sequence's low-res run at `budget` (substeps, iterations; the scene's settings
    else), with each of kernels_to_time: a kernel's name as `frame_kernel` steps with that kernel."""
    substeps, iterations = budget
    simulation = point_simulation(settings, f"{substeps}x{iterations}")
    kernels = kernels_to_time(solver_settings(simulation), wp.get_device(device),
                              len(read_rest_mesh(sequence.scene)[0]), harmonic=False)   # a low-res run has none
    return faster_kernel({kernel: float(np.median(solve_ms(
        {**simulation, "solver": {**simulation["solver"], "frame_kernel": kernel}}, "low", (sequence.scene,),
        device, sequence.settled_low))) for kernel in kernels})


def free_high_res_ms(settings: dict, subdiv: str, sequence: TimedSequence, device: str) -> float:
    """Median ms a frame of the sequence's free high-res run at the scene's solver budget."""
    return float(np.median(solve_ms(simulation_settings(settings), "free",
                                    (sequence.scene, subdiv, sequence.sim_low), device, sequence.settled_high)))
