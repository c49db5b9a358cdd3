"""Item 7 of issue 13, the learning stages' side: dataset.h5 and operators.h5 record the low-res rest mesh they
derive from (`source_mesh`, carried on from subdiv.h5), so `train` refuses operators made from another mesh even
where its faces, and so every check of shapes and indices, agree with the dataset's (once rc 0: the network
trained on tables of other geometry). And a split that names one frame twice, in one split or in two, is
refused where dataset.h5 is read: a frame trained on twice as often, or a test frame trained on, would skew the
training and flatter the test error."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from geometry.loop_subdivision import loop_subdivide
from hostile import ARCH, assert_refused, files_in, run_in_process
from pipeline import operators, train
from pipeline.core import cli
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, mesh_fingerprint, write_csr
from stage_inputs import grid


def _train(dataset: Path, operators_h5: Path, out: Path, capsys):
    return run_in_process(train.main, dataset, operators_h5, out / "model.pt", out / "train.h5", *ARCH,
                          "--epochs", "1", "--quiet", capsys=capsys)


def test_dataset_and_operators_carry_the_rest_mesh_of_their_subdivision(valid, tmp_path):
    """The valid artifacts are made from hostile.write_simulations' 5 x 5 sheet; operators of a mesh file, whose
    origin is unknown, carry no fingerprint (there is nothing to compare it with)."""
    expected = mesh_fingerprint(*grid(5))
    for name in ("subdiv.h5", "dataset.h5", "operators.h5"):
        with h5py.File(valid / name, "r") as f:
            assert f.attrs[SOURCE_MESH] == expected, name
    vertices, faces = grid(5)
    obj = tmp_path / "sheet.obj"
    obj.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
                   + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    cli.run(operators.main, [str(obj), str(tmp_path / "operators.h5"), "--conv", "RC7", "--levels", "1", "--quiet"])
    with h5py.File(tmp_path / "operators.h5", "r") as f:
        assert SOURCE_MESH not in f.attrs


@pytest.fixture(scope="module")
def moved_operators(tmp_path_factory) -> Path:
    """operators.h5 (as the valid one: RC7, 3 levels) of the subdivision of the valid sheet sheared along y: the
    same faces, other positions."""
    folder = tmp_path_factory.mktemp("moved")
    vertices, faces = grid(5)
    vertices = vertices + [0.0, 0.0, 0.2] * vertices[:, [1]]
    subdivision, high_faces = loop_subdivide(vertices, faces, 1)
    with atomic_h5(folder / "subdiv.h5", "subdivide") as out:
        out.attrs[SOURCE_MESH] = mesh_fingerprint(vertices, faces)
        write_csr(out, "S", subdivision)
        out["vertices"] = subdivision @ vertices
        out["faces"] = high_faces.astype(np.int32)
    cli.run(operators.main, [str(folder / "subdiv.h5"), str(folder / "operators.h5"), "--conv", "RC7", "--levels",
                             "3", "--quiet"])
    return folder / "operators.h5"


def test_train_refuses_operators_of_another_mesh_with_the_same_faces(valid, moved_operators, tmp_path, capsys):
    with h5py.File(moved_operators, "r") as f, h5py.File(valid / "dataset.h5", "r") as d:
        assert np.array_equal(f["levels/0/faces"][()], d["faces"][()])     # no face check can tell them apart
    out = tmp_path / "out"
    out.mkdir()
    run = _train(valid / "dataset.h5", moved_operators, out, capsys)
    assert_refused(run, str(moved_operators), "made from another mesh than", str(valid / "dataset.h5"),
                   folder=out, before=set())


def _repeat_in_train(f: h5py.File) -> None:
    f["split/train"][1] = f["split/train"][0]


def _in_train_and_test(f: h5py.File) -> None:
    f["split/test"][0] = f["split/train"][0]


def _in_test_and_held_out(f: h5py.File) -> None:
    test_ids = f["split/test"][()]
    del f["split/held_out"]
    f["split/held_out"] = test_ids[:1]


SPOILED_SPLITS = {"a frame twice in train": _repeat_in_train, "a frame in train and test": _in_train_and_test,
                  "a frame in test and held_out": _in_test_and_held_out}


@pytest.mark.parametrize("case", SPOILED_SPLITS)
def test_a_frame_named_twice_by_the_split_is_refused(valid, tmp_path, capsys, case):
    spoiled = tmp_path / "inputs" / "dataset.h5"
    spoiled.parent.mkdir()
    shutil.copy(valid / "dataset.h5", spoiled)
    with h5py.File(spoiled, "r+") as f:
        SPOILED_SPLITS[case](f)
    out = tmp_path / "out"
    out.mkdir()
    run = _train(spoiled, valid / "operators.h5", out, capsys)
    assert_refused(run, str(spoiled), "'split/train'", "disjoint", folder=out, before=set())
    assert files_in(tmp_path / "inputs") == {"dataset.h5"}
