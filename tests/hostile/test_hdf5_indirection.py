"""Item 5 of issue 41: an artifact whose data lies in other files (external storage, an external link, a virtual
dataset) is refused when it is opened. libhdf5 follows each silently: a sim_low.h5 whose positions were stored
"in" another file once passed pipeline.dataset and carried that file's bytes into dataset.h5."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from hostile import assert_refused, dataset_command, files_in, run_in_process
from pipeline import dataset


def _elsewhere(folder: Path, shape: tuple[int, ...], dtype: np.dtype) -> tuple[Path, Path]:
    """A raw file of plausible numbers (standing for any local file) and an HDF5 file holding them as 'data'."""
    raw, other = folder / "secret.bin", folder / "other.h5"
    np.full(shape, 0.125, dtype=dtype).tofile(raw)
    with h5py.File(other, "w") as f:
        f["data"] = np.full(shape, 0.125, dtype=dtype)
    return raw, other


def _reach_out(f: h5py.File, name: str, kind: str, folder: Path) -> None:
    """Replace dataset `name` of `f` by one of the same shape whose data comes from outside the file."""
    shape, dtype = f[name].shape, f[name].dtype
    del f[name]
    raw, other = _elsewhere(folder, shape, dtype)
    if kind == "external storage":
        f.create_dataset(name, shape=shape, dtype=dtype, external=[(str(raw), 0, h5py.h5f.UNLIMITED)])
    elif kind == "external link":
        f[name] = h5py.ExternalLink(str(other), "data")
    else:
        layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
        layout[...] = h5py.VirtualSource(str(other), "data", shape=shape)
        f.create_virtual_dataset(name, layout)


@pytest.mark.parametrize("artifact, name", [("sequence/sim_low.h5", "positions"), ("subdiv.h5", "S/data")])
@pytest.mark.parametrize("kind, problem", [("external storage", "keeps its data in external files"),
                                           ("external link", "is an external link"),
                                           ("virtual dataset", "is a virtual dataset")])
def test_data_from_other_files_is_refused(valid, tmp_path, capsys, artifact, name, kind, problem):
    inputs = tmp_path / "inputs"
    shutil.copytree(valid, inputs, ignore=shutil.ignore_patterns("dataset.h5", "operators.h5"))
    with h5py.File(inputs / artifact, "a") as f:
        _reach_out(f, name, kind, tmp_path)
    before = files_in(inputs)
    run = run_in_process(dataset.main, *dataset_command(inputs / "subdiv.h5", inputs / "dataset.h5", inputs),
                         capsys=capsys)
    assert_refused(run, f"{inputs / artifact}: ", problem, repr(name), folder=inputs, before=before)
