"""tradeoff.h5, written by the `tradeoff` stage: one row per point of the speed-accuracy grid (docs/artifacts.md,
section "tradeoff.h5"); and what the stage reads of the scene's dataset.h5 to score a high-res run against the
scene's (which sequence and frame each test and held-out frame is, and the frame of reference)."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import ColumnTable, atomic_h5, open_artifact

STAGE = "tradeoff"
# Columns (each a dataset of one value per row) and their units.
STRING_COLUMNS = ("method", "network", "harmonic_every", "sim_low_kernel")
# The learned path with the fused bf16 network (model.fused_network, CUDA) in place of the fp32 one: its ms, its
# error against the fp32 network (largest |difference| over the largest fp32 displacement), the row's total and
# speedup with it.
FUSED_COLUMNS = ("ms_net_fused", "fused_error", "ms_total_fused", "speedup_fused")
INT_COLUMNS = ("substeps", "iterations", "trained_substeps", "trained_iterations", "params")
FLOAT_COLUMNS = ("l1_test", "l2_test", "l1_heldout", "l2_heldout", "ms_sim_low", "ms_sim_low_other", "ms_subdiv",
                 "ms_net", "ms_sim_high_run", "ms_total", "ms_sim_high", "speedup", *FUSED_COLUMNS)
COLUMNS = (*STRING_COLUMNS, *INT_COLUMNS, *FLOAT_COLUMNS)
# NaN: the scene has no held-out motion (l1_heldout, l2_heldout); one frame kernel timed (ms_sim_low_other: the
# two step the cloth alike on the device, or a row without a low-res solve); no fused network timed (the fused
# columns: a CPU timing, where the fused network does not run, or a row without a network)
NAN_WHEN_ABSENT = ("l1_heldout", "l2_heldout", "ms_sim_low_other", *FUSED_COLUMNS)
TABLE = ColumnTable(STRING_COLUMNS, INT_COLUMNS, FLOAT_COLUMNS, NAN_WHEN_ABSENT)
# Columns that tables written before 2026-11-29 lack (docs/data/tradeoff_pants_paper_h100.h5 among them), and the
# table such a file holds. Its low-res solves were the sweeps' (the only frame kernel the stage timed then), and the
# other kernel was not timed.
FRAME_KERNEL_COLUMNS = ("sim_low_kernel", "ms_sim_low_other")
TABLE_BEFORE_FRAME_KERNELS = ColumnTable(tuple(c for c in STRING_COLUMNS if c not in FRAME_KERNEL_COLUMNS), INT_COLUMNS,
                                         tuple(c for c in FLOAT_COLUMNS if c not in FRAME_KERNEL_COLUMNS),
                                         NAN_WHEN_ABSENT)
# `method` of a row: the learned path (low-res run, Loop subdivision, network), Loop subdivision of the low-res run
# alone, or a high-res run of another budget or harmonic schedule than the scene's.
LEARNED, LOOP, HIGH_RES = "learned", "loop", "high_res"
METHODS = (LEARNED, LOOP, HIGH_RES)
NO_NETWORK = "none"      # `network` of a row without one
SIM_HIGH_MEANING = ("the high-res solver at the reference budget with the scene's physics (body and self collision "
                    "where it has them), not held to a "
                    "low-res run (the paper's reference), one sequence alone, timed in the stage's job beside the "
                    "learned path's low-res solve, Loop subdivision and network")


@dataclasses.dataclass(frozen=True)
class Reference:
    """The scene's own high-res run: the ground truth every row is scored against, and the budget at which the
    high-res solver, free, is the time to beat (`ms_sim_high`)."""
    substeps: int
    iterations: int
    harmonic_every: str


@dataclasses.dataclass(frozen=True)
class Tradeoff:
    """The grid's rows: `columns` maps every name of COLUMNS to one value per row (strings as str arrays; errors
    in scene units, NaN for a split the scene lacks; times in ms per frame)."""
    columns: dict[str, np.ndarray]
    device: str                 # where the learned path was timed, in words
    threads: int                # torch CPU threads of that timing
    reference: Reference

    def __len__(self) -> int:
        return len(self.columns["method"])


def write_tradeoff(path: str | os.PathLike, config: Mapping[str, Any], table: Tradeoff) -> None:
    with atomic_h5(path, STAGE, config) as f:
        TABLE.write(f, table.columns)
        ref = table.reference
        f.attrs.update(device=table.device, threads=table.threads, reference_substeps=ref.substeps,
                       reference_iterations=ref.iterations, reference_harmonic_every=ref.harmonic_every,
                       error_unit="scene units (~m); the report shows x 1e-3", time_unit="ms per frame",
                       ms_sim_high=SIM_HIGH_MEANING,
                       fused_columns=f"{', '.join(FUSED_COLUMNS)}: the learned path with the fused bf16 network; "
                                     f"NaN: not timed (a CPU timing: it runs on CUDA only; a row without a network)")


def read_tradeoff(path: str | os.PathLike) -> Tradeoff:
    """A tradeoff.h5; one written before the frame kernels' columns reads with the values they stand for there (the
    sweeps for every row with a low-res solve, the other kernel not timed)."""
    with open_artifact(path) as f:
        before = not any(name in f for name in FRAME_KERNEL_COLUMNS)
        columns = (TABLE_BEFORE_FRAME_KERNELS if before else TABLE).read(f)
        unknown = sorted(set(columns["method"]) - set(METHODS))
        if unknown:
            raise PipelineError(f"{path}: 'method' holds '{unknown[0]}', not one of {', '.join(METHODS)}")
        if before:
            columns["sim_low_kernel"] = np.where(columns["method"] == HIGH_RES, "", "sweeps")
            columns["ms_sim_low_other"] = np.full(len(columns["method"]), np.nan)
        attrs = f.attrs
        reference = Reference(int(attrs["reference_substeps"]), int(attrs["reference_iterations"]),
                              str(attrs["reference_harmonic_every"]))
        return Tradeoff(columns, str(attrs["device"]), int(attrs["threads"]), reference)
