"""convs.h5, written by the `convs` stage: one row per training run of the operator comparison (docs/artifacts.md,
section "convs.h5")."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, open_artifact, read, read_or_nan, read_strings

STAGE = "convs"
SPLITS = ("train", "test", "heldout")       # column suffixes; eval.h5 calls the last one held_out
TERMS = ("l1", "l2")
KINDS = ("RC", "EC", "SP", "SPD")
OURS = ("RC", "EC")                          # the paper's operators; SP and SPD are the spiral ones it compares to
STRING_COLUMNS = ("task", "kind", "arch")
INT_COLUMNS = ("length", "seed", "params")
ERROR_COLUMNS = tuple(f"{term}_{split}" for split in SPLITS for term in TERMS)
LOOP_COLUMNS = tuple(f"loop_{name}" for name in ERROR_COLUMNS)
FLOAT_COLUMNS = ("width", *ERROR_COLUMNS, *LOOP_COLUMNS, "ms_inference", "train_seconds")
COLUMNS = (*STRING_COLUMNS, *INT_COLUMNS, *FLOAT_COLUMNS)
NAN_WHEN_ABSENT = tuple(name for name in FLOAT_COLUMNS if name.endswith("_heldout"))   # no held-out motion


@dataclasses.dataclass(frozen=True)
class Convs:
    """The grid's rows: `columns` maps every name of COLUMNS to one value per row (strings as str arrays; errors in
    scene units, NaN for a split the scene lacks; ms per frame; training wall seconds)."""
    columns: dict[str, np.ndarray]
    device: str             # where the networks were timed, in words (each evaluation's own)

    def __len__(self) -> int:
        return len(self.columns["task"])


def write_convs(path: str | os.PathLike, config: Mapping[str, Any], table: Convs) -> None:
    with atomic_h5(path, STAGE, config) as f:
        for name in STRING_COLUMNS:
            f.create_dataset(name, data=np.array(table.columns[name], dtype="S"))
        for name in INT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.int64))
        for name in FLOAT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.float64))
        f.attrs.update(device=table.device, error_unit="scene units (~m); the report shows x 1e-3",
                       time_unit="ms per frame (median over the evaluation's timed frames)")


def read_convs(path: str | os.PathLike) -> Convs:
    with open_artifact(path) as f:
        columns = {name: read_strings(f, name) for name in STRING_COLUMNS}
        columns.update({name: read(f, name, np.int64) for name in INT_COLUMNS})
        columns.update({name: read_or_nan(f, name) if name in NAN_WHEN_ABSENT else read(f, name, np.float64)
                        for name in FLOAT_COLUMNS})
        n_rows = len(columns["task"])
        if any(values.shape != (n_rows,) for values in columns.values()):
            raise PipelineError(f"{path}: its columns do not all have one value per row ({n_rows})")
        unknown = sorted(set(columns["kind"]) - set(KINDS))
        if unknown:
            raise PipelineError(f"{path}: 'kind' holds '{unknown[0]}', not one of {', '.join(KINDS)}")
        device = f.attrs.get("device")
        if not isinstance(device, str):
            raise PipelineError(f"{path}: attribute 'device' missing: not a convs.h5 of experiments.convs")
        return Convs(columns, device)
