"""convs.h5, written by the `convs` stage: one row per training run of the operator comparison (docs/artifacts.md,
section "convs.h5")."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import ColumnTable, atomic_h5, config_of, open_artifact

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
TABLE = ColumnTable(STRING_COLUMNS, INT_COLUMNS, FLOAT_COLUMNS, NAN_WHEN_ABSENT)


@dataclasses.dataclass(frozen=True)
class Convs:
    """The grid's rows: `columns` maps every name of COLUMNS to one value per row (strings as str arrays; errors in
    scene units, NaN for a split the scene lacks; ms per frame; training wall seconds)."""
    columns: dict[str, np.ndarray]
    device: str             # where the networks were timed, in words (each evaluation's own)
    recipes: dict = dataclasses.field(default_factory=dict)   # task -> the train.h5 flags its runs share (config)

    def __len__(self) -> int:
        return len(self.columns["task"])


def write_convs(path: str | os.PathLike, config: Mapping[str, Any], table: Convs) -> None:
    with atomic_h5(path, STAGE, config) as f:
        TABLE.write(f, table.columns)
        f.attrs.update(device=table.device, error_unit="scene units (~m); the report shows x 1e-3",
                       time_unit="ms per frame (median over the evaluation's timed frames)")


def read_convs(path: str | os.PathLike) -> Convs:
    with open_artifact(path) as f:
        columns = TABLE.read(f)
        unknown = sorted(set(columns["kind"]) - set(KINDS))
        if unknown:
            raise PipelineError(f"{path}: 'kind' holds '{unknown[0]}', not one of {', '.join(KINDS)}")
        device = f.attrs.get("device")
        if not isinstance(device, str):
            raise PipelineError(f"{path}: attribute 'device' missing: not a convs.h5 of experiments.convs")
        recipes = config_of(f).get("recipes")
        return Convs(columns, device, recipes if isinstance(recipes, dict) else {})
