"""Item 10 of issue 13: an artifact whose HDF5 metadata is damaged (64 bytes overwritten inside an object header,
as a bad sector or a botched copy leaves it) is one error naming the file. h5py reports such damage as KeyError,
RuntimeError or OSError from wherever the reader happens to touch the file; each once ended the stage in a
traceback."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from hostile import assert_refused, dataset_command, run_stage

# The objects of subdiv.h5 whose headers are overwritten, and where in the header (bytes past its start).
DAMAGED = [("S", 40), ("S/indices", 16), ("faces", 16)]


def _header_address(path: Path, name: str) -> int:
    with h5py.File(path) as f:
        return h5py.h5o.get_info(f[name].id).addr


@pytest.mark.parametrize("name, offset", DAMAGED)
def test_damaged_metadata_is_one_clear_error(valid, tmp_path, name, offset):
    damaged = tmp_path / "inputs" / "subdiv.h5"
    damaged.parent.mkdir()
    shutil.copy(valid / "subdiv.h5", damaged)
    with open(damaged, "r+b") as f:
        f.seek(_header_address(damaged, name) + offset)
        f.write(np.random.default_rng(1).integers(0, 256, 64, dtype=np.uint8).tobytes())
    out = tmp_path / "out"
    run = run_stage("dataset", *dataset_command(damaged, out / "dataset.h5", valid))
    assert_refused(run, str(damaged), "damaged or unreadable HDF5 file")
    assert not out.exists()
