"""tradeoff.h5, written by the `tradeoff` stage: one row per point of the speed-accuracy grid (docs/artifacts.md,
section "tradeoff.h5"); and the two timing figures it reads from the artifacts of other stages, which their
own modules do not read back yet (a sim's `solve_ms`, an evaluation's inference times and network)."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import h5py
import numpy as np

from pipeline.artifacts.h5 import FLOAT32_MAX, atomic_h5, config_of, open_artifact, read
from pipeline.errors import PipelineError

STAGE = "tradeoff"
# Columns (each a dataset of one value per row) and their units.
INT_COLUMNS = ("substeps", "iterations", "params")
FLOAT_COLUMNS = ("l1_test", "l2_test", "l1_heldout", "l2_heldout", "ms_sim_low", "ms_subdiv", "ms_net", "ms_total",
                 "ms_sim_high", "speedup")
NAN_WHEN_ABSENT = ("l1_heldout", "l2_heldout")     # NaN: the scene has no held-out motion


@dataclasses.dataclass(frozen=True)
class Tradeoff:
    """The grid's rows: `network` names the network of each row ("none": Loop subdivision alone), `columns`
    maps every name of INT_COLUMNS and FLOAT_COLUMNS to one value per row (errors in scene units, NaN for
    a split the scene lacks; times in ms per frame)."""
    network: list[str]
    columns: dict[str, np.ndarray]
    device: str                 # where the learned path was timed, in words
    threads: int                # torch CPU threads of that timing
    sim_high_batch: int         # sequences the high-res run stepped together (ms_sim_high is per sequence)


def write_tradeoff(path: str | os.PathLike, config: Mapping[str, Any], table: Tradeoff) -> None:
    with atomic_h5(path, STAGE, config) as f:
        f.create_dataset("network", data=np.array(table.network, dtype="S"))
        for name in INT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.int64))
        for name in FLOAT_COLUMNS:
            f.create_dataset(name, data=np.asarray(table.columns[name], dtype=np.float64))
        f.attrs.update(device=table.device, threads=table.threads, sim_high_batch=table.sim_high_batch,
                       error_unit="scene units (~m); the report shows x 1e-3", time_unit="ms per frame")


def read_tradeoff(path: str | os.PathLike) -> Tradeoff:
    with open_artifact(path) as f:
        network = [name.decode() for name in read(f, "network")]
        columns = {name: read(f, name, np.int64) for name in INT_COLUMNS}
        columns.update({name: _read_float_column(f, name) for name in FLOAT_COLUMNS})
        if any(len(values) != len(network) for values in columns.values()):
            raise PipelineError(f"{path}: its columns do not all have one value per row ({len(network)})")
        return Tradeoff(network, columns, str(f.attrs["device"]), int(f.attrs["threads"]),
                        int(f.attrs["sim_high_batch"]))


def _read_float_column(f: h5py.File, name: str) -> np.ndarray:
    """A float column; NaN only in the columns of NAN_WHEN_ABSENT (read() refuses NaN anywhere)."""
    column = f.get(name)
    if name in NAN_WHEN_ABSENT and isinstance(column, h5py.Dataset) and column.dtype.kind == "f":
        data = np.asarray(column[()], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            if not np.all(np.isnan(data) | (np.abs(data) <= FLOAT32_MAX)):
                raise PipelineError(f"{f.filename}: dataset '{name}' contains inf or values beyond float32's range")
        return data
    return read(f, name, np.float64)


def read_solve_ms(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """A sim_low.h5 or sim_high.h5's ms per frame of its solve (frames 1.., frame 0 being the initial state) and
    the sequences its batch stepped together (whose total those ms are)."""
    with open_artifact(path) as f:
        solve_ms = read(f, "solve_ms", np.float64)
        batch = int(f.attrs.get("batch", 1))
    if solve_ms.ndim != 1 or len(solve_ms) < 2 or batch < 1 or not np.all(np.isfinite(solve_ms)):
        raise PipelineError(f"{path}: 'solve_ms' must hold finite ms of at least one solved frame (batch >= 1)")
    return solve_ms[1:], batch


@dataclasses.dataclass(frozen=True)
class NetworkTiming:
    """What an eval.h5 says of its network's speed and size."""
    inference_ms: np.ndarray    # (T,) ms per timed frame on the deployment path
    device: str                 # where it ran, in words
    params: int                 # learnable parameters
    name: str                   # "<conv> x<width>", from the recorded model spec


def read_network_timing(path: str | os.PathLike) -> NetworkTiming:
    with open_artifact(path) as f:
        times = read(f, "inference_ms", np.float64)
        spec = config_of(f).get("model_spec", {})
        try:
            device, params = str(f.attrs["device"]), int(f.attrs["parameter_count"])
            name = f"{spec['conv']} x{float(spec['width']):g}"
        except (KeyError, TypeError, ValueError) as err:
            raise PipelineError(f"{path}: {err} missing or malformed: not an eval.h5 of pipeline.evaluate") from None
    if times.ndim != 1 or len(times) == 0 or not np.all(np.isfinite(times)):
        raise PipelineError(f"{path}: 'inference_ms' must hold the finite ms of at least one timed frame")
    return NetworkTiming(times, device, params, name)
