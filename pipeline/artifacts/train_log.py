"""train.h5, written by the `train` stage beside model.pt: the loss curves of one training
(docs/artifacts.md, section "train.h5")."""
from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from model.training import History
from pipeline.artifacts.h5 import atomic_h5

STAGE = "train"


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
