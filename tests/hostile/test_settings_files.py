"""Items 9 and 10 of issue 13 for configs and settings.json: numbers that cannot work (NaN, inf, 1e400, values past
the schema's bounds), a hand-edited settings.json with a key missing (the solver once ran with its own default of
8 substeps) or of the wrong type (a TypeError traceback), and YAML errors, which PyYAML spreads over several lines.
Each is one `error: <file>: <problem>` line naming the key, before anything is built."""
from __future__ import annotations

import json
import os
import stat

import pytest

import hostile
from hostile import REPO, assert_refused, files_in, run_in_process, run_stage
from pipeline import scene
from pipeline.core.config import read_settings, write_settings


@pytest.fixture(scope="module")
def patch_settings() -> dict:
    return hostile.patch_settings()


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def edit(settings: dict) -> None:
        group = settings
        for key in keys[:-1]:
            group = group[key]
        group[keys[-1]] = value
    return edit


def _drop(group: str, key: str):
    def edit(settings: dict) -> None:
        del settings[group][key]
    return edit


# name: (the hand edit of settings.json, words the error must hold). json.dumps writes NaN and inf as the
# literals NaN and Infinity, which Python's json module reads back as numbers.
EDITS = {
    "NaN dt": (_set("solver", "dt", float("nan")), ("solver.dt", "nan", "not a finite number")),
    "infinite damping": (_set("solver", "damping", float("inf")), ("solver.damping", "not a finite number")),
    "origin beyond float32": (_set("mesh", "origin", [1e39, 0.0, 0.0]), ("mesh.origin.0", "not a finite number")),
    "substeps 100000": (_set("solver", "substeps", 100000), ("solver.substeps", "maximum of 100")),
    "frames 10 million": (_set("frames", 10**7), ("frames", "maximum of 100000")),
    "dt of 5 s": (_set("solver", "dt", 5.0), ("solver.dt", "maximum of 0.1")),
    "seed past 32 bits": (_set("training", "seed", 2**40), ("training.seed", "maximum")),
    "negative input noise": (_set("training", "input_noise", -0.1), ("training.input_noise", "minimum")),
    "missing solver.substeps": (_drop("solver", "substeps"), ("missing key 'substeps' in solver",)),
    "missing high_res": (lambda s: s.pop("high_res"), ("missing key 'high_res' in top level",)),
    "substeps as text": (_set("solver", "substeps", "8"), ("solver.substeps", "'8' is not of type 'integer'")),
    "solver as a list": (_set("solver", [1, 2]), ("solver", "is not of type 'object'")),
    "unknown key": (_set("solver", "stifness", 1.0), ("unknown key 'stifness' in solver",)),
    "device gpu7": (_set("device", "gpu7"), ("device", "gpu7", "does not match")),
    "key of another generator": (_set("mesh", "garment", "pants"), ("key 'garment' in mesh applies only when",)),
}


@pytest.mark.parametrize("case", EDITS)
def test_hand_edited_settings_are_one_clear_error(patch_settings, tmp_path, capsys, case):
    edit, words = EDITS[case]
    settings = json.loads(json.dumps(patch_settings))
    edit(settings)
    path = tmp_path / "settings.json"
    path.write_text(json.dumps(settings, indent=2))
    before = files_in(tmp_path)
    run = run_in_process(scene.main, path, tmp_path / "scene.h5", "--sequence", "train_000", capsys=capsys)
    assert_refused(run, str(path), *words, folder=tmp_path, before=before)


def test_a_number_too_large_for_a_double_is_refused(patch_settings, tmp_path, capsys):
    """1e400 is valid JSON; Python reads it as inf."""
    path = tmp_path / "settings.json"
    path.write_text(json.dumps(patch_settings, indent=2).replace('"dt": 0.0166666667', '"dt": 1e400'))
    assert "1e400" in path.read_text()
    run = run_in_process(scene.main, path, tmp_path / "scene.h5", capsys=capsys)
    assert_refused(run, str(path), "solver.dt", "inf")


def test_simulate_refuses_settings_without_substeps_instead_of_assuming_8(patch_settings, tmp_path):
    """Once `simulate low` ran on (rc 0) with the solver's default substeps; now it stops before the scene is read."""
    settings = json.loads(json.dumps(patch_settings))
    del settings["solver"]["substeps"]
    path = tmp_path / "settings.json"
    path.write_text(json.dumps(settings))
    before = files_in(tmp_path)
    run = run_stage("simulate", "low", path, tmp_path / "scene.h5", tmp_path / "sim_low.h5", "--quiet")
    assert_refused(run, str(path), "missing key 'substeps' in solver", folder=tmp_path, before=before)


def test_complete_settings_read_back_as_written(patch_settings, tmp_path):
    write_settings(patch_settings, tmp_path / "settings.json")
    assert read_settings(tmp_path / "settings.json") == patch_settings


def test_settings_are_written_through_the_safe_write_helper(patch_settings, tmp_path):
    """With the mode any output gets (mkstemp alone makes 0600), and an unusable path is one error."""
    write_settings(patch_settings, tmp_path / "settings.json")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE((tmp_path / "settings.json").stat().st_mode) == 0o666 & ~umask
    (tmp_path / "file").write_text("")
    before = files_in(tmp_path)
    run = run_stage("settings", REPO / "workflow_config.yaml", "patch", tmp_path / "file" / "settings.json")
    assert_refused(run, str(tmp_path / "file" / "settings.json"), "is a file, not a folder", folder=tmp_path,
                   before=before)


# A config broken in the middle of a flow sequence: PyYAML reports where the sequence began and where it broke,
# each with the offending line and a caret.
BROKEN_YAML = "profile: cpu\ndefaults: [1, 2\nscenes: {}\n"


def test_yaml_error_is_one_line_with_its_place(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(BROKEN_YAML)
    run = run_stage("settings", path, "patch", tmp_path / "settings.json")
    # line 3 column 7 is the ':' after `scenes`; the sequence opened at line 2 column 11
    assert_refused(run, f"{path}:3:7: not valid YAML: expected ',' or ']', but got ':' "
                        f"(while parsing a flow sequence at 2:11)")
    assert files_in(tmp_path) == {"config.yaml"}


@pytest.mark.parametrize("literal", [".nan", ".inf", "-.inf", "1.0e+39"])
def test_non_finite_number_in_a_yaml_config_is_named(tmp_path, literal):
    text = (REPO / "workflow_config.yaml").read_text()
    assert "    dt: 0.0166666667" in text
    path = tmp_path / "config.yaml"
    path.write_text(text.replace("    dt: 0.0166666667", f"    dt: {literal}"))
    run = run_stage("settings", path, "patch", tmp_path / "settings.json")
    assert_refused(run, str(path), "defaults.solver.dt", "not a finite number")
    assert files_in(tmp_path) == {"config.yaml"}
