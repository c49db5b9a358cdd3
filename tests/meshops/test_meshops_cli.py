"""The `operators` stage CLI: the HDF5 layout of issue #3, and one clear error (and no output) on bad input."""
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from meshops_shapes import mesh_of, operators_of
from pipeline.core.cli import run
from pipeline.operators import main

ROOT = Path(__file__).resolve().parents[2]


def _operators(argv):
    run(main, [str(a) for a in argv] + ["--quiet"])


@pytest.fixture(scope="module")
def pants_artifact(tmp_path_factory):
    folder = tmp_path_factory.mktemp("operators")
    vertices, faces = mesh_of("pants")
    trimesh.Trimesh(vertices, faces, process=False).export(folder / "pants.obj")
    _operators([folder / "pants.obj", folder / "operators.h5"])
    return folder / "operators.h5"


def test_layout_of_every_level(pants_artifact):
    levels = operators_of("pants")
    with h5py.File(pants_artifact, "r") as f:
        assert f.attrs["stage"] == "operators" and f.attrs["n_levels"] == 11
        assert json.loads(f.attrs["conv"]) == ["RC13", "EC13", "SP13", "SPD13"]
        assert json.loads(f.attrs["config"])["levels"] == 10
        for index, level in enumerate(levels):
            group = f[f"levels/{index}"]
            assert group["vertices"].dtype == np.float32 and group["faces"].dtype == np.int32
            assert np.allclose(group["vertices"][()], level.vertices, atol=1e-6)
            assert np.array_equal(group["faces"][()], level.faces)
            assert group.attrs["fixed_vertex"] == level.fixed_vertex
            assert np.array_equal(group["geodesic_sources"][()], level.geodesic_sources)
            for name in ("RC13", "EC13", "SP13", "SPD13"):
                table = group[f"conv/{name}"]
                assert table.dtype == np.int32 and table.attrs["filter_length"] == 13
                assert table.attrs["kind"] == name[:-2] and table.attrs["padding_index"] == 0
                assert np.array_equal(table[()], level.conv[name])
            assert group["conv/EC13"].attrs["rc_fallback_vertices"] == level.ec_fallbacks["EC13"]
            if index < 10:
                assert np.array_equal(group["pool"][()], level.coarsening.pool)
                assert np.array_equal(group["unpool"][()], level.coarsening.unpool)
                assert group["pool"].dtype == np.int32 and group["unpool"].dtype == np.int32
            else:
                assert "pool" not in group and "unpool" not in group


def test_h5_mesh_input_and_custom_tables(tmp_path):
    vertices, faces = mesh_of("square")
    with h5py.File(tmp_path / "subdiv.h5", "w") as f:
        f["vertices"], f["faces"] = vertices, faces.astype(np.int32)
    _operators([tmp_path / "subdiv.h5", tmp_path / "out.h5", "--conv", "RC9, SPD5", "--levels", "2"])
    with h5py.File(tmp_path / "out.h5", "r") as f:
        assert f.attrs["n_levels"] == 3 and sorted(f["levels/0/conv"]) == ["RC9", "SPD5"]
        assert f["levels/2/conv/RC9"].shape == (len(f["levels/2/vertices"]), 9)
        assert np.array_equal(f["levels/0/vertices"][()], vertices.astype(np.float32))


def _write_obj(path, vertices, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def _square():
    return [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]]


def _bad_inputs(folder):
    vertices, faces = _square()
    _write_obj(folder / "non_manifold.obj", vertices + [[0.5, 0.5, 1]], faces + [[2, 0, 4]])
    _write_obj(folder / "zero_area.obj", [[0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, 1, 0]],
               [[0, 2, 3], [2, 1, 3], [0, 1, 2]])
    _write_obj(folder / "nan.obj", [[0, 0, 0], [1, 0, 0], ["nan", 1, 0], [0, 1, 0]], faces)
    # OBJ readers drop unused vertices, so this one comes as an HDF5 mesh.
    with h5py.File(folder / "unreferenced.h5", "w") as f:
        f["vertices"], f["faces"] = np.array(vertices + [[5.0, 5, 5]]), np.array(faces)
    (folder / "unreadable.ply").write_bytes(bytes(range(256)) * 3)
    return {"non_manifold.obj": "non-manifold", "zero_area.obj": "zero area", "nan.obj": "NaN",
            "unreferenced.h5": "belongs to no face", "unreadable.ply": "cannot read mesh",
            "missing.obj": "does not exist"}


def test_each_bad_input_is_one_clear_error_and_leaves_no_output(tmp_path, capsys):
    for name, problem in _bad_inputs(tmp_path).items():
        out = tmp_path / f"{name}.operators.h5"
        with pytest.raises(SystemExit) as exit_info:
            _operators([tmp_path / name, out])
        message = capsys.readouterr().err.strip()
        assert exit_info.value.code == 2
        assert message.startswith("error: ") and name in message and problem in message, message
        assert len(message.splitlines()) == 1
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".h5") == ["unreferenced.h5"]


@pytest.mark.parametrize("argv, problem", [(["--conv", "RC13,QQ3"], "--conv"), (["--conv", "RC13,RC13"], "named twice"),
                                           (["--conv", " , "], "no convolution"),
                                           (["--levels", "-1"], "--levels"),
                                           (["--quadric-threshold", "nan"], "--quadric-threshold")])
def test_bad_options_are_refused(tmp_path, capsys, argv, problem):
    vertices, faces = _square()
    _write_obj(tmp_path / "square.obj", vertices, faces)
    with pytest.raises(SystemExit):
        _operators([tmp_path / "square.obj", tmp_path / "out.h5", *argv])
    assert problem in capsys.readouterr().err
    assert not (tmp_path / "out.h5").exists()


def test_runs_as_a_module(tmp_path):
    vertices, faces = mesh_of("two_triangles")
    _write_obj(tmp_path / "pair.obj", vertices, faces)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    command = [sys.executable, "-m", "pipeline.operators", str(tmp_path / "pair.obj"), str(tmp_path / "out.h5"),
               "--levels", "1"]
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "level 1: 3 vertices" in done.stderr
    with h5py.File(tmp_path / "out.h5", "r") as f:
        row = f["levels/0/conv/RC13"][0]
        assert row[0] == 1 and sorted(row[row > 0]) == [1, 2, 3, 4] and np.sum(row == 0) == 9
