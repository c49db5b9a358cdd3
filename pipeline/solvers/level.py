"""What the simulate stage asks of a solver kind: the runs it makes of each sequence (its levels: the cloth's low-
and high-res runs), and, for one level and a batch of sequences, the batch made ready to step.

A level's `prepare` is the solver's adapter: it reads the sequences' artifacts, turns them into the solver's model
(sim/<name>/), builds the solver with one world per sequence and says what each frame's inputs are and what a
run records beside its positions. The stage (pipeline/simulate.py) does the rest the same way for every kind:
the frame loop, batching, writing and timing."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from pipeline.artifacts.simulation import SimulationRun
from sim.solver import Solver


@dataclass(frozen=True, eq=False)
class PreparedBatch:
    """Sequences ready to step together, world w the sequence of scene_paths[w]."""
    label: str                                       # the run's name in the log and in errors, e.g. "low-res"
    solver: Solver
    scene_paths: Sequence[str]                       # world w's scene file: an error at world w names it
    n_frames: Sequence[int]                          # world w's frames (the batch steps max(n_frames))
    work: str                                        # what stepping one frame of one world does, for the log
    inputs: Callable[[int], Any]                     # frame f -> the solver's inputs of every world at its end
    run: Callable[[int, np.ndarray, np.ndarray, float], SimulationRun]
    # (w, world w's positions (F, V, 3), the batch's ms per frame (F,), setup seconds) -> what world w's file holds
    measure: Callable[[int, int, int, np.ndarray], None] | None = None
    # (w, first, end, positions (F, B, V, 3)): work on frames first..end-1 of world w as soon as they are stepped,
    # on the stage's threads while the device steps on (what `run` then records besides the positions)
    tangled: Callable[[np.ndarray], str] | None = None
    # a world's positions (F, V, 3) -> why its run is unusable though it finished (a cloth caught and stretched
    # between limbs), "" if it is not: the stage drops such a run of a motion library's window
    summary: Callable[[], str] | None = None
    # what the solver says of the stepping once it is done, for the log (the cloth: its self-contact lists' growth)


# (settings, each sequence's input files, device, quiet, threads, settled) -> the batch ready to step; `settled`
# (V, 3) is the last frame of the scene's settle run at this level (None without one), where each sequence whose
# scene starts settled (a motion library's window) starts
Prepare = Callable[[dict, Sequence[tuple[str, ...]], str, bool, int, np.ndarray | None], PreparedBatch]


@dataclass(frozen=True, eq=False)
class Level:
    """One run a solver kind makes of each sequence."""
    inputs: tuple[str, ...]       # one sequence's files before its OUT, the sequence's scene file first
    meaning: str                  # what the run is (--help)
    prepare: Prepare


def frame_of_each(per_sequence: Sequence[np.ndarray], f: int) -> np.ndarray:
    """(B, ...) frame f of each sequence's per-frame array, its last frame for a sequence that has ended: a batch
    steps its longest sequence's frames, a shorter sequence's world holding its last inputs (its extra frames are
    not stored)."""
    return np.stack([a[min(f, len(a) - 1)] for a in per_sequence])
