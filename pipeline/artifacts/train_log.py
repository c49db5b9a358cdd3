"""train.h5, written by the `train` stage beside model.pt: the loss curves of one training
(docs/artifacts.md, section "train.h5"); read back by `evaluate` for the report's training curve."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import h5py
import numpy as np

from model.training import History
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, open_artifact

STAGE = "train"
TRAIN_TOTAL, TEST_TOTAL = "epoch/train_total", "epoch/test_total"


def write_train_log(path: str | os.PathLike, history: History, config: Mapping[str, Any], device: str,
                    parameter_count: int, seconds: float) -> None:
    with atomic_h5(path, STAGE, config) as f:
        for split in ("train", "test"):
            for term, values in getattr(history, split).items():
                f.create_dataset(f"epoch/{split}_{term}", data=np.asarray(values, dtype=np.float64))
        f.create_dataset("epoch/seconds", data=np.asarray(history.epoch_seconds))
        f.create_dataset("batch/total", data=np.asarray(history.batch_total, dtype=np.float64))
        f.attrs.update(device=device, parameter_count=parameter_count, epochs=history.epochs_done,
                       resumed_from_epoch=history.resumed_from_epoch, wall_seconds=seconds,
                       loss_unit="scene units (~m); normal term dimensionless")
        f["epoch"].attrs["meaning"] = ("per-epoch mean losses: train_* over the epoch's batches while training, "
                                       "test_* on the test frames after the epoch; total = eq. 7")


@dataclasses.dataclass(frozen=True)
class TrainLog:
    """What a report shows of a training: the loss per epoch (eq. 7's weighted total), train and test."""

    train_total: np.ndarray      # (E,) float64, mean over each epoch's batches while training
    test_total: np.ndarray       # (E,) float64, on the test frames after each epoch


def read_train_log(path: str | os.PathLike) -> TrainLog:
    """The loss curves of train.h5. A diverged training's NaN or inf losses are kept as they are (the curve
    shows where it diverged), unlike `h5.read`, which refuses them."""
    with open_artifact(path) as f:
        curves = []
        for name in (TRAIN_TOTAL, TEST_TOTAL):
            if name not in f or not isinstance(f[name], h5py.Dataset) or f[name].ndim != 1 \
                    or not np.issubdtype(f[name].dtype, np.floating):
                raise PipelineError(f"{path}: missing dataset '{name}' of one float per epoch")
            curves.append(np.asarray(f[name][()], dtype=np.float64))
    if len(curves[0]) == 0 or len(curves[0]) != len(curves[1]):
        raise PipelineError(f"{path}: '{TRAIN_TOTAL}' ({len(curves[0])}) and '{TEST_TOTAL}' ({len(curves[1])}) "
                            f"must have one entry per epoch, at least one")
    return TrainLog(*curves)
