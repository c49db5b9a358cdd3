"""Issue 37's own hand: a user's closed hand OBJ and bone file (here the procedural hand's own, in centimetres and
off the origin: tests/hand_files.py) go through the hand scene's whole chain with one overlay and one command,
`snakemake results/mine/`, at a tiny size: hand.h5 records the files, the FEM runs start at the file's skin in
metres, the network beats linear blend skinning on the test frames; and editing the bone file makes the hand again."""
from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from hand_files import FRAMES, hand_config, write_hand_files
from pipeline.artifacts.evaluation import read_errors
from pipeline.artifacts.hand import read_hand, read_hand_run
from pipeline.core.meshio import load_mesh
from workflow_runs import build, planned_counts, snakemake, tail

OFFSET = (0.05, 0.9, -0.2)        # metres: where the user's hand is
MINE = {"like": "hand", "mesh": {"generator": "hand_file", "file": "hand.obj", "bones": "bones.yaml",
                                 "units": "auto", "tet_spacing": 0.012}}


@pytest.fixture(scope="module")
def mine(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("hand_file")
    write_hand_files(workdir, 0.01, offset=OFFSET, units="cm")     # coarser, the skin pinches a fingertip off
    config = hand_config(workdir, scenes={"mine": MINE})
    run = build(workdir, "results/mine/", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    return workdir, config


def test_a_users_hand_runs_end_to_end_and_the_network_beats_skinning(mine):
    workdir, _ = mine
    out = workdir / "results" / "mine"
    with h5py.File(out / "hand.h5") as f:
        assert f.attrs["units"] == "cm" and f.attrs["file"] == "hand.obj" and f.attrs["bones"] == "bones.yaml"
    hand = read_hand(out / "hand.h5")
    vertices, _ = load_mesh(workdir / "hand.obj")
    np.testing.assert_allclose(hand.skin_vertices, 0.01 * vertices, atol=1e-12)
    run = read_hand_run(out / "sequences" / "train_000" / "fem.h5", len(vertices))
    assert run.skin.shape == (FRAMES, len(vertices), 3) and run.converged.mean() > 0.9
    np.testing.assert_allclose(run.skin[0], hand.skin_vertices, atol=1e-6)
    assert np.linalg.norm(run.skin[-1] - run.skin[0], axis=1).max() > 0.01            # the hand moved
    errors = read_errors(out / "eval.h5")
    assert errors["network"]["test"]["l1"] < errors["predictor"]["test"]["l1"]
    assert "hand.obj and bones.yaml (the user's files" in (out / "report.md").read_text()


def test_editing_the_bone_file_makes_the_hand_again(mine):
    workdir, config = mine
    bones = workdir / "bones.yaml"
    # An edit (Snakemake passes over a file only touched: its checksum is the one recorded), written after hand.h5.
    bones.write_text(bones.read_text() + "# the little finger's tip moved\n")
    later = (workdir / "results" / "mine" / "hand.h5").stat().st_mtime + 10
    os.utime(bones, (later, later))
    run = snakemake(workdir, "results/mine/", "-n", "--configfile", str(config))
    assert run.returncode == 0, tail(run)
    assert planned_counts(run).get("hand_scene") == 1
