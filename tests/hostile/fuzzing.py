"""The machinery of test_fuzz.py: seeded mutations of an artifact, and its consumer stage run in a process of its
own with a time limit, so that a segfault shows as a signal and a hang as a timeout.

Each case's stage runs in a child forked from a forkserver that has imported every stage once (`PRELOAD`):
starting `python -m pipeline.<stage>` anew costs 2-4 s of imports per case, a fork none. The child runs the stage
the way its `__main__` does (`pipeline.core.cli.run`), its stderr going to a file, so what it reports and how it ends
are those of the command line; the forkserver is a fresh interpreter that has run no torch or Warp work, so
forking it is safe.
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Sequence

import h5py
import numpy as np
import torch

from pipeline import dataset, evaluate, simulate, train
from pipeline.core import cli

STAGES = {"simulate": simulate.main, "dataset": dataset.main, "train": train.main, "evaluate": evaluate.main}
# Imported by the forkserver before it forks. Python 3.11's forkserver imports these with its own sys.path, which
# lacks this folder, so this module cannot be among them: the stages are (the project is installed), and they are
# what takes the time.
PRELOAD = [f"pipeline.{stage}" for stage in STAGES]
# Printed by Warp's native library when it starts on a machine without an NVIDIA driver: not the stage's output.
WARP_DRIVER_NOTICE = "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver"


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    stage: str
    argv: list[str]
    out: Path                # the folder the stage writes into
    log: Path                # its stderr


@dataclasses.dataclass(frozen=True)
class Outcome:
    exitcode: int | None     # negative: killed by that signal; None: still running at the time limit (killed)
    stderr: str
    seconds: float


def _run_case(case: Case) -> None:
    """In the child: the stage as its command line runs it (stdout dropped), then exit with its status."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    os.dup2(os.open(case.log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), 2)
    try:
        cli.run(STAGES[case.stage], case.argv)     # its SystemExit sets the child's exit status
    except Exception:
        traceback.print_exc()        # what the interpreter does with an uncaught exception
        sys.exit(1)


def run_cases(cases: Sequence[Case], timeout: float, workers: int = 2) -> dict[str, Outcome]:
    """Run every case, `workers` at a time, each stopped after `timeout` seconds."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    waiting, running, outcomes = list(cases), {}, {}
    while waiting or running:
        while waiting and len(running) < workers:
            case = waiting.pop(0)
            process = context.Process(target=_run_case, args=(case,))
            process.start()
            running[case.name] = (case, process, time.monotonic())
        time.sleep(0.05)
        for name, (case, process, start) in list(running.items()):
            elapsed = time.monotonic() - start
            if process.is_alive() and elapsed < timeout:
                continue
            hung = process.is_alive()
            if hung:
                process.kill()
            process.join()
            outcomes[name] = Outcome(None if hung else process.exitcode, case.log.read_text(errors="replace"),
                                     elapsed)
            del running[name]
    return outcomes


# Byte-level damage of any file.
def flip_bytes(path: Path, rng: np.random.Generator) -> str:
    data = bytearray(path.read_bytes())
    at = rng.choice(len(data), size=int(rng.integers(1, 17)), replace=False)
    for i in at:
        data[i] ^= int(rng.integers(1, 256))
    path.write_bytes(bytes(data))
    return f"{len(at)} bytes flipped"


def overwrite_64(path: Path, rng: np.random.Generator) -> str:
    at = int(rng.integers(0, path.stat().st_size - 64))
    with open(path, "r+b") as f:
        f.seek(at)
        f.write(rng.integers(0, 256, 64, dtype=np.uint8).tobytes())
    return f"64 bytes at {at}"


def truncate(path: Path, rng: np.random.Generator) -> str:
    size = int(rng.integers(0, path.stat().st_size))
    os.truncate(path, size)
    return f"truncated to {size} bytes"


# HDF5-level damage: well-formed files whose contents are wrong.
def _pick(f: h5py.File, rng: np.random.Generator, wanted=lambda d: True) -> str | None:
    names = []
    f.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) and wanted(obj) else None)
    return str(rng.choice(sorted(names))) if names else None


def _replace(f: h5py.File, name: str, data: np.ndarray) -> None:
    del f[name]
    f[name] = data


def nan_entry(f: h5py.File, rng: np.random.Generator) -> str:
    name = _pick(f, rng, lambda d: d.dtype.kind == "f" and d.size > 0)
    if name is None:
        return delete_dataset(f, rng)
    data = f[name][()]
    data.flat[int(rng.integers(data.size))] = rng.choice([np.nan, np.inf, -np.inf])
    f[name][...] = data
    return f"NaN/inf in '{name}'"


def index_out_of_range(f: h5py.File, rng: np.random.Generator) -> str:
    name = _pick(f, rng, lambda d: d.dtype.kind in "iu" and d.size > 0)
    if name is None:
        return nan_entry(f, rng)
    data = f[name][()]
    bounds = np.iinfo(data.dtype)
    value = rng.choice([-1, -7, data.size * 1000 + 3, bounds.max, bounds.min])
    data.flat[int(rng.integers(data.size))] = np.clip(value, bounds.min, bounds.max)
    f[name][...] = data
    return f"entry {value} in '{name}'"


def wrong_shape(f: h5py.File, rng: np.random.Generator) -> str:
    name = _pick(f, rng, lambda d: d.size > 1)
    data = f[name][()]
    shapes = {"one row fewer": data[:-1], "flattened": data.ravel(), "an extra axis": data[..., None],
              "transposed": data.T}
    how = str(rng.choice(sorted(shapes)))
    _replace(f, name, shapes[how])
    return f"'{name}' {how}"


def wrong_dtype(f: h5py.File, rng: np.random.Generator) -> str:
    name = _pick(f, rng, lambda d: d.dtype.kind in "iuf" and d.size > 0)
    data = f[name][()]
    kinds = {"int8": data.astype(np.int8) if data.dtype.kind == "f" else data.astype(np.float64) + 0.5,
             "text": np.char.encode(data.astype(str), "ascii"), "complex": data.astype(np.complex64)}
    how = str(rng.choice(sorted(kinds)))
    _replace(f, name, kinds[how])
    return f"'{name}' as {how}"


def delete_dataset(f: h5py.File, rng: np.random.Generator) -> str:
    name = _pick(f, rng)
    del f[name]
    return f"'{name}' deleted"


def spoil_attr(f: h5py.File, rng: np.random.Generator) -> str:
    owners = [f] + [f[n] for n in sorted(_names(f))]
    owners = [o for o in owners if len(o.attrs)]
    owner = owners[int(rng.integers(len(owners)))]
    key = str(rng.choice(sorted(owner.attrs)))
    value = [b"garbage", np.nan, -1, np.arange(3)][int(rng.integers(4))]
    owner.attrs[key] = value
    return f"attr '{key}' of '{owner.name}' = {value!r}"


def damage_header(path: Path, rng: np.random.Generator) -> str:
    """64 random bytes over the start of an object's header (its messages: dataspace, datatype, layout, links),
    the metadata damage a bad sector or a botched copy leaves."""
    with h5py.File(path, "r") as f:
        name = str(rng.choice(sorted(_names(f))))
        at = h5py.h5o.get_info(f[name].id).addr + int(rng.integers(0, 48))
    with open(path, "r+b") as raw:
        raw.seek(at)
        raw.write(rng.integers(0, 256, 64, dtype=np.uint8).tobytes())
    return f"64 bytes over the header of '{name}' at {at}"


def _names(f: h5py.File) -> list[str]:
    names = []
    f.visit(names.append)
    return names


BYTE_MUTATIONS = {"flip_bytes": flip_bytes, "overwrite_64": overwrite_64, "truncate": truncate}
H5_FILE_MUTATIONS = {"damage_header": damage_header}
H5_MUTATIONS = {"nan_entry": nan_entry, "index_out_of_range": index_out_of_range, "wrong_shape": wrong_shape,
                "wrong_dtype": wrong_dtype, "delete_dataset": delete_dataset, "spoil_attr": spoil_attr}


# model.pt: a torch zip of plain values and tensors (pipeline.artifacts.model).
def _tensor_name(state: dict, rng: np.random.Generator) -> str:
    return str(rng.choice(sorted(k for k, v in state["state_dict"].items() if v.is_floating_point())))


def weights_nan(state: dict, rng: np.random.Generator) -> str:
    name = _tensor_name(state, rng)
    state["state_dict"][name].view(-1)[int(rng.integers(state["state_dict"][name].numel()))] = float("nan")
    return f"NaN in '{name}'"


def weights_shape(state: dict, rng: np.random.Generator) -> str:
    name = _tensor_name(state, rng)
    state["state_dict"][name] = torch.zeros(state["state_dict"][name].numel() + 1)
    return f"'{name}' of another shape"


def drop_entry(state: dict, rng: np.random.Generator) -> str:
    group = state if rng.random() < 0.5 else state["state_dict"]
    key = str(rng.choice(sorted(group)))
    del group[key]
    return f"'{key}' dropped"


def spoil_spec(state: dict, rng: np.random.Generator) -> str:
    key = str(rng.choice(sorted(state["spec"])))
    state["spec"][key] = [None, -3, "D8 X", 1e9][int(rng.integers(4))]
    return f"spec '{key}' = {state['spec'][key]!r}"


MODEL_MUTATIONS = {"weights_nan": weights_nan, "weights_shape": weights_shape, "drop_entry": drop_entry,
                   "spoil_spec": spoil_spec}


def mutate(path: Path, kind: str, rng: np.random.Generator) -> str:
    """Spoil the file at `path` in place with mutation `kind`; returns what was done, for the failure message."""
    if kind in BYTE_MUTATIONS:
        return BYTE_MUTATIONS[kind](path, rng)
    if kind in H5_FILE_MUTATIONS:
        return H5_FILE_MUTATIONS[kind](path, rng)
    if kind in H5_MUTATIONS:
        with h5py.File(path, "r+") as f:
            return H5_MUTATIONS[kind](f, rng)
    state = torch.load(path, weights_only=True)
    done = MODEL_MUTATIONS[kind](state, rng)
    torch.save(state, path)
    return done
