"""tradeoff.h5, written by the `tradeoff` stage: one row per point of the speed-accuracy grid (docs/artifacts.md,
section "tradeoff.h5"); and what the stage reads of the scene's dataset.h5 to score a high-res run against the
scene's (which sequence and frame each test and held-out frame is, and the frame of reference)."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import h5py
import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, open_artifact, read, read_or_nan, read_strings

STAGE = "tradeoff"
# Columns (each a dataset of one value per row) and their units.
STRING_COLUMNS = ("method", "network", "harmonic_every")
INT_COLUMNS = ("substeps", "iterations", "trained_substeps", "params")
FLOAT_COLUMNS = ("l1_test", "l2_test", "l1_heldout", "l2_heldout", "ms_sim_low", "ms_subdiv", "ms_net",
                 "ms_sim_high_run", "ms_total", "ms_sim_high", "speedup")
COLUMNS = (*STRING_COLUMNS, *INT_COLUMNS, *FLOAT_COLUMNS)
NAN_WHEN_ABSENT = ("l1_heldout", "l2_heldout")     # NaN: the scene has no held-out motion
# `method` of a row: the learned path (low-res run, Loop subdivision, network), Loop subdivision of the low-res run
# alone, or a high-res run of another budget or harmonic schedule than the scene's.
LEARNED, LOOP, HIGH_RES = "learned", "loop", "high_res"
METHODS = (LEARNED, LOOP, HIGH_RES)
NO_NETWORK = "none"      # `network` of a row without one


@dataclasses.dataclass(frozen=True)
class Reference:
    """The scene's own high-res run, the ground truth every row is scored against and timed beside."""
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
    sim_high_batch: int         # sequences the high-res run stepped together (ms_sim_high is per sequence)
    reference: Reference

    def __len__(self) -> int:
        return len(self.columns["method"])


def write_tradeoff(path: str | os.PathLike, config: Mapping[str, Any], table: Tradeoff) -> None:
    with atomic_h5(path, STAGE, config) as f:
        for name in STRING_COLUMNS:
            f.create_dataset(name, data=np.array(table.columns[name], dtype="S"))
        for name in INT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.int64))
        for name in FLOAT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.float64))
        ref = table.reference
        f.attrs.update(device=table.device, threads=table.threads, sim_high_batch=table.sim_high_batch,
                       reference_substeps=ref.substeps, reference_iterations=ref.iterations,
                       reference_harmonic_every=ref.harmonic_every,
                       error_unit="scene units (~m); the report shows x 1e-3", time_unit="ms per frame")


def read_tradeoff(path: str | os.PathLike) -> Tradeoff:
    with open_artifact(path) as f:
        columns = {name: read_strings(f, name) for name in STRING_COLUMNS}
        columns.update({name: read(f, name, np.int64) for name in INT_COLUMNS})
        columns.update({name: _read_float_column(f, name) for name in FLOAT_COLUMNS})
        n_rows = len(columns["method"])
        if any(values.shape != (n_rows,) for values in columns.values()):
            raise PipelineError(f"{path}: its columns do not all have one value per row ({n_rows})")
        unknown = sorted(set(columns["method"]) - set(METHODS))
        if unknown:
            raise PipelineError(f"{path}: 'method' holds '{unknown[0]}', not one of {', '.join(METHODS)}")
        attrs = f.attrs
        reference = Reference(int(attrs["reference_substeps"]), int(attrs["reference_iterations"]),
                              str(attrs["reference_harmonic_every"]))
        return Tradeoff(columns, str(attrs["device"]), int(attrs["threads"]), int(attrs["sim_high_batch"]),
                        reference)


def _read_float_column(f: h5py.File, name: str) -> np.ndarray:
    """A float column; NaN only in the columns of NAN_WHEN_ABSENT (read() refuses NaN anywhere)."""
    return read_or_nan(f, name) if name in NAN_WHEN_ABSENT else read(f, name, np.float64)
