"""Item 6 of issue 13: every index array read from an artifact is checked (range, shape, integer type; a
sparse matrix's indptr rising from 0 to nnz) before scipy, numpy or Warp index with it. Without the checks,
an out-of-range S/indices made `dataset` and `simulate high` die of SIGSEGV."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from hostile import ARCH, assert_refused, dataset_command, run_in_process, run_stage
from pipeline import train


def _set(name, index, value):
    def change(f):
        f[name][index] = value
    return change


def _as_float(name):
    def change(f):
        data = f[name][()]
        del f[name]
        f[name] = data + 0.5
    return change


def _indptr_not_monotone(f):
    f["S/indptr"][1] = f["S/indptr"][-1]


def _indptr_short_of_nnz(f):
    f["S/indptr"][-1] -= 1


def _shape_of_other_rows(f):
    f["S/shape"][0] += 1


# name: (the change to subdiv.h5, words the error must hold)
SUBDIV = {
    "S index past the columns": (_set("S/indices", 0, 10**6), ("'S/indices'", "outside")),
    "negative S index": (_set("S/indices", 3, -1), ("'S/indices'", "outside")),
    "indptr not monotone": (_indptr_not_monotone, ("sparse matrix 'S'", "indptr")),
    "indptr short of nnz": (_indptr_short_of_nnz, ("sparse matrix 'S'", "indptr")),
    "shape of other rows": (_shape_of_other_rows, ("'S/indptr'", "shape")),
    "face index past the vertices": (_set("faces", (0, 1), 10**6), ("'faces'", "outside")),
    "negative face index": (_set("faces", (2, 0), -2), ("'faces'", "outside")),
    "faces as floats": (_as_float("faces"), ("'faces'", "integer")),
}

# name: (the change to operators.h5, words the error must hold)
OPERATORS = {
    "conv id past the vertices": (_set("levels/0/conv/RC7", (0, 1), 10**6), ("'levels/0/conv/RC7'", "outside")),
    "pool id past the vertices": (_set("levels/0/pool", (0, 0), 10**6), ("'levels/0/pool'", "outside")),
    "negative unpool id": (_set("levels/1/unpool", 0, -5), ("'levels/1/unpool'", "outside")),
}


def _spoiled(valid: Path, folder: Path, artifact: str, change) -> Path:
    path = folder / "inputs" / artifact
    path.parent.mkdir()
    shutil.copy(valid / artifact, path)
    with h5py.File(path, "r+") as f:
        change(f)
    return path


@pytest.mark.parametrize("case", SUBDIV)
def test_spoiled_subdivision_is_one_clear_error_for_dataset(valid, tmp_path, case):
    change, words = SUBDIV[case]
    subdiv = _spoiled(valid, tmp_path, "subdiv.h5", change)
    out = tmp_path / "out"
    run = run_stage("dataset", *dataset_command(subdiv, out / "dataset.h5", valid))
    assert_refused(run, str(subdiv), *words)
    assert not out.exists()


def test_spoiled_faces_are_one_clear_error_for_operators(valid, tmp_path):
    subdiv = _spoiled(valid, tmp_path, "subdiv.h5", _set("faces", (0, 1), 10**6))
    out = tmp_path / "out"
    run = run_stage("operators", subdiv, out / "operators.h5", "--conv", "RC7", "--levels", "3", "--quiet")
    assert_refused(run, str(subdiv), "'faces'", "outside")
    assert not out.exists()


@pytest.mark.parametrize("case", OPERATORS)
def test_spoiled_operators_are_one_clear_error_for_train(valid, tmp_path, capsys, case):
    """In this process (torch checks its own gathers: an escaped index would raise, not crash)."""
    change, words = OPERATORS[case]
    operators = _spoiled(valid, tmp_path, "operators.h5", change)
    out = tmp_path / "out"
    run = run_in_process(train.main, valid / "dataset.h5", operators, out / "model.pt", out / "train.h5", *ARCH,
                         "--epochs", "1", "--quiet", capsys=capsys)
    assert_refused(run, str(operators), *words)
    assert not out.exists()


def test_valid_subdivision_reads_back_exactly(valid):
    """The checks refuse only what is wrong: the valid file's S is the matrix that was written."""
    from geometry.loop_subdivision import loop_subdivide
    from pipeline.artifacts.subdiv import read_subdivision
    from stage_inputs import grid

    vertices, faces = grid(5)
    S, high_faces = loop_subdivide(vertices, faces, 1)
    read = read_subdivision(valid / "subdiv.h5")
    assert (read.S != S).nnz == 0 and np.array_equal(read.faces, high_faces)
