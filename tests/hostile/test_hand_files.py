"""Issue 37: a user's hand files that cannot make a hand stop the hand_scene stage with one `error:` line naming the
file at fault (the skin's or the bone file) and the problem, and leave nothing behind: an open or non-manifold
skin, wrong units, a bone file that is no YAML, whose joints form a cycle, name an unknown parent, lack a role or
hold NaN, a joint or a bone outside the skin, a missing file. The files are the procedural hand's own
(tests/hand_files.py), spoiled one way each."""
from __future__ import annotations

import shutil

import pytest
import yaml

from hand_files import change_joints, write_hand_files
from hostile import REPO, assert_refused, files_in, run_in_process
from pipeline import hand_scene
from pipeline.core.config import load_config, resolve_scene, simulation_settings, write_settings

SPACING = 0.01      # coarser, the procedural skin pinches fingertips off or cuts inside their joints


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pristine")
    write_hand_files(folder, SPACING, units="cm")
    return folder


@pytest.fixture
def folder(pristine, tmp_path):
    """A copy of the hand's files and the settings of a scene made of them (hand.obj, bones.yaml, in cm)."""
    for name in ("hand.obj", "bones.yaml"):
        shutil.copy(pristine / name, tmp_path / name)
    write_scene_settings(tmp_path)
    return tmp_path


def write_scene_settings(folder, **mesh) -> None:
    config = load_config(REPO / "workflow_config.yaml")
    config["scenes"]["mine"] = {"like": "hand", "mesh": {
        "generator": "hand_file", "file": str(folder / "hand.obj"), "bones": str(folder / "bones.yaml"),
        "units": "auto", "tet_spacing": SPACING, **mesh}}
    write_settings(simulation_settings(resolve_scene(config, "mine", "cpu")), folder / "simulation.json")


def refused(folder, capsys, *words) -> None:
    before = files_in(folder)
    run = run_in_process(hand_scene.main, folder / "simulation.json", folder / "hand.h5", capsys=capsys)
    assert_refused(run, *words, folder=folder, before=before)


def spoil_joints(folder, **change) -> None:
    """bones.yaml with each named joint's fields updated (None: the joint removed)."""
    document = change_joints(yaml.safe_load((folder / "bones.yaml").read_text()), **change)
    (folder / "bones.yaml").write_text(yaml.safe_dump(document))


def test_the_pristine_files_make_a_hand(folder, capsys):
    run = run_in_process(hand_scene.main, folder / "simulation.json", folder / "hand.h5", "--quiet", capsys=capsys)
    assert run.returncode == 0, run.stderr
    assert (folder / "hand.h5").is_file()


def test_an_open_skin_is_refused(folder, capsys):
    lines = (folder / "hand.obj").read_text().splitlines()
    (folder / "hand.obj").write_text("\n".join(lines[:-1]) + "\n")          # the last face gone: a hole
    refused(folder, capsys, "hand.obj", "not closed", "1 hole")


def test_a_non_manifold_skin_is_refused(folder, capsys):
    text = (folder / "hand.obj").read_text()
    first_face = next(line for line in text.splitlines() if line.startswith("f "))
    a, b = first_face.split()[1:3]
    vertices = sum(line.startswith("v ") for line in text.splitlines())
    # A fin: a third face on an edge two faces share already.
    (folder / "hand.obj").write_text(text + f"v 0 0 40\nf {a} {b} {vertices + 1}\n")
    refused(folder, capsys, "hand.obj", "non-manifold")


def test_wrong_units_are_refused(folder, capsys):
    write_scene_settings(folder, units="m")
    refused(folder, capsys, "hand.obj", "wrong units", "mesh.units")


@pytest.mark.parametrize("change, words", [
    ({"index_2": {"parent": "index_3"}}, ("cycle of parents", "'index_2'")),
    ({"index_2": {"parent": "metacarpal_9"}}, ("parent 'metacarpal_9' is no joint",)),
    ({"ring_tip": None}, ("missing joint 'ring_tip'",)),
    ({"palm": {"position": [0.0, float("nan"), 0.0]}}, ("joint 'palm'", "three finite numbers")),
    ({"index_tip": {"position": [0.0, 100.0, 0.0]}}, ("joint 'index_tip'", "outside the hand's skin")),
], ids=["cycle", "unknown parent", "missing joint", "nan", "joint outside"])
def test_a_bone_file_that_makes_no_hand_is_refused_naming_the_joint(folder, capsys, change, words):
    spoil_joints(folder, **change)
    refused(folder, capsys, "bones.yaml", *words)


def test_a_bone_that_leaves_the_skin_between_two_joints_inside_it_is_refused(folder, capsys):
    index_tip = next(j for j in yaml.safe_load((folder / "bones.yaml").read_text())["joints"]
                     if j["name"] == "index_tip")
    spoil_joints(folder, thumb_tip={"position": index_tip["position"]})   # across the air to the index's tip
    refused(folder, capsys, "bones.yaml", "thumb_2 bone", "leaves the hand's skin")


# Ten levels of aliases, each repeating the last ten times: 10^10 values if walked or printed, a few lines here.
ALIAS_BOMB = "joints:\n  - {name: a, position: &l0 [0, 0, 0]}\n" + "".join(
    f"  - {{name: j{k}, position: &l{k} [{', '.join([f'*l{k - 1}'] * 10)}]}}\n" for k in range(1, 11))


@pytest.mark.parametrize("text, words", [("joints: [a, b\n", ("not valid YAML",)),
                                         ("- 1\n- 2\n", ("maps 'joints'",)),
                                         (b"\xff\xfe joints", ("cannot read the bone file",)),
                                         (ALIAS_BOMB, ("joint 'j1'", "three finite numbers")),
                                         ('joints: [{name: "wrist\\nerror: forged"}]\n', ("printable",))],
                         ids=["yaml", "not a map", "not text", "alias bomb", "newline in a name"])
def test_a_bone_file_that_is_no_bone_file_is_refused(folder, capsys, text, words):
    (folder / "bones.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
    refused(folder, capsys, "bones.yaml", *words)


def test_a_missing_bone_file_is_refused(folder, capsys):
    (folder / "bones.yaml").unlink()
    refused(folder, capsys, "bones.yaml", "does not exist")
