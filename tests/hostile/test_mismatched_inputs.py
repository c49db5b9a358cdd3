"""Item 7 of issue 13: inputs that do not belong together. A subdiv.h5 made from another mesh with as many vertices
as the scene's once passed `simulate high` and `dataset` (rc 0: S multiplies any positions of the right count);
now every artifact derived from the low-res rest mesh carries its fingerprint (`source_mesh`) and the stages
compare them. Negative split ids, which once aliased test frames, are refused where dataset.h5 is read."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from hostile import ARCH, assert_refused, files_in, run_in_process, run_stage, write_patch_scene
from pipeline import dataset, simulate, subdivide, train
from pipeline.core import cli
from pipeline.core.h5 import SOURCE_MESH, mesh_fingerprint
from pipeline.artifacts.scene import read_rest_mesh


def _flip_an_edge(faces: np.ndarray) -> np.ndarray:
    """The faces with the first interior edge flipped: (a, b, c) and (b, a, d) become (a, d, c) and (d, b, c),
    the other diagonal of the same quad, so the mesh keeps its vertices, count and positions alike."""
    faces = faces.copy()
    for i, (a, b, c) in enumerate(faces):
        for a, b, c in ((a, b, c), (b, c, a), (c, a, b)):
            twin = [j for j, face in enumerate(faces) if j != i and {a, b} <= set(face)]
            if twin:
                d = next(v for v in faces[twin[0]] if v not in (a, b))
                faces[i], faces[twin[0]] = (a, d, c), (d, b, c)
                return faces
    raise AssertionError("no interior edge")


# Other meshes of as many vertices as the scene's, made from its rest mesh: the same faces over vertices moved
# (once accepted by both stages), and the same vertices with one edge flipped.
OTHER_MESHES = {"moved": lambda v, f: (v + [0.0, 0.01, 0.0] * v[:, [0]], f),      # y sheared along x
                "flipped": lambda v, f: (v, _flip_an_edge(f))}


@pytest.fixture(scope="module")
def patch(tmp_path_factory) -> Path:
    """The patch scene's first sequence, run: settings.json, sequence/{scene,sim_low,sim_high}.h5 and its
    subdiv.h5 (one level); and <kind>_subdiv.h5, the subdivision of each of OTHER_MESHES."""
    folder = tmp_path_factory.mktemp("patch")
    sequence = folder / "sequence"
    write_patch_scene(sequence)
    settings, scene = sequence / "settings.json", sequence / "scene.h5"
    vertices, faces = read_rest_mesh(scene)
    meshes = {scene: folder / "subdiv.h5"}
    for kind, make in OTHER_MESHES.items():
        with h5py.File(folder / f"{kind}_mesh.h5", "w") as f:
            f["vertices"], f["faces"] = make(vertices, faces)
        meshes[folder / f"{kind}_mesh.h5"] = folder / f"{kind}_subdiv.h5"
    for mesh, out in meshes.items():
        cli.run(subdivide.main, [str(mesh), str(out), "--settings", str(settings), "--levels", "1", "--quiet"])
    cli.run(simulate.main, ["low", str(settings), str(scene), str(sequence / "sim_low.h5"), "--quiet"])
    cli.run(simulate.main, ["high", str(settings), str(scene), str(folder / "subdiv.h5"), str(sequence / "sim_low.h5"),
                            str(sequence / "sim_high.h5"), "--quiet"])
    return folder


def test_every_artifact_of_a_scene_carries_its_rest_mesh(patch):
    """The fingerprint is that of the scene's rest mesh as read back, in every artifact made from it; those of
    the other meshes differ."""
    vertices, faces = read_rest_mesh(patch / "sequence" / "scene.h5")
    expected = mesh_fingerprint(vertices, faces)
    for name in ("sequence/scene.h5", "subdiv.h5", "sequence/sim_low.h5", "sequence/sim_high.h5"):
        with h5py.File(patch / name, "r") as f:
            assert f.attrs[SOURCE_MESH] == expected, name
    for kind in OTHER_MESHES:
        with h5py.File(patch / f"{kind}_subdiv.h5", "r") as f:
            assert f.attrs["n_low_vertices"] == len(vertices) and f.attrs[SOURCE_MESH] != expected, kind


@pytest.mark.parametrize("kind", OTHER_MESHES)
def test_simulate_high_refuses_a_subdivision_of_another_mesh(patch, tmp_path, kind):
    sequence, other = patch / "sequence", patch / f"{kind}_subdiv.h5"
    before = files_in(tmp_path)
    run = run_stage("simulate", "high", sequence / "settings.json", sequence / "scene.h5", other,
                    sequence / "sim_low.h5", tmp_path / "sim_high.h5", "--quiet")
    assert_refused(run, str(other), "made from another mesh than", str(sequence / "scene.h5"), folder=tmp_path,
                   before=before)


@pytest.mark.parametrize("kind", OTHER_MESHES)
def test_dataset_refuses_a_subdivision_of_another_mesh(patch, tmp_path, capsys, kind):
    """In this process: the check comes before any frame is read."""
    command, other = [tmp_path / "dataset.h5", patch / "sequence", "--quiet"], patch / f"{kind}_subdiv.h5"
    before = files_in(tmp_path)
    run = run_in_process(dataset.main, other, *command, capsys=capsys)
    assert_refused(run, str(other), "made from another mesh than",
                   str(patch / "sequence" / "sim_low.h5"), folder=tmp_path, before=before)
    assert run_in_process(dataset.main, patch / "subdiv.h5", *command, capsys=capsys).returncode == 0


def test_train_refuses_a_negative_split_id(valid, tmp_path, capsys):
    """-1 would alias the last frame, a test frame, into the training set."""
    spoiled = tmp_path / "inputs" / "dataset.h5"
    spoiled.parent.mkdir()
    shutil.copy(valid / "dataset.h5", spoiled)
    with h5py.File(spoiled, "r+") as f:
        f["split/train"][0] = -1
    out = tmp_path / "out"
    run = run_in_process(train.main, spoiled, valid / "operators.h5", out / "model.pt", out / "train.h5", *ARCH,
                         "--epochs", "1", "--quiet", capsys=capsys)
    assert_refused(run, str(spoiled), "'split/train'", "outside")
    assert not out.exists()
