"""workflow_config.yaml: schema validation, profile overlays, clear errors."""
import copy
import subprocess
import sys

import pytest
import yaml

from pipeline.config import deep_merge, load_config, resolve_scene, validate_config
from pipeline.errors import PipelineError

CONFIG = yaml.safe_load(open("workflow_config.yaml"))


def test_shipped_config_is_valid_and_every_scene_resolves_in_every_profile():
    validate_config(CONFIG)
    for profile in CONFIG["profiles"]:
        for scene in CONFIG["scenes"]:
            settings = resolve_scene(CONFIG, scene, profile)
            assert settings["scene"] == scene and settings["profile"] == profile
            assert settings["solver"]["compression_allowance"] == 0.75


def test_profiles_change_sizes():
    cpu, paper = resolve_scene(CONFIG, "flag", "cpu"), resolve_scene(CONFIG, "flag", "paper")
    assert paper["solver"]["substeps"] == 8 and paper["solver"]["iterations"] == 75
    assert paper["mesh"]["max_edge"] == 0.08 and paper["device"].startswith("cuda")
    assert cpu["solver"]["iterations"] < 75 and cpu["device"] == "cpu"


def test_deep_merge_keeps_unmentioned_keys():
    assert deep_merge({"a": {"b": 1, "c": 2}}, {"a": {"c": 3}}) == {"a": {"b": 1, "c": 3}}


@pytest.mark.parametrize("mutate, message", [
    (lambda c: c["scenes"]["flag"].update(solver={"stifness": 1.0}), "unknown key 'stifness' in scenes.flag.solver"),
    (lambda c: c.update(colour="red"), "unknown key 'colour' in top level"),
    (lambda c: c.pop("defaults"), "missing key 'defaults'"),
    (lambda c: c["defaults"]["solver"].update(substeps=0), "defaults.solver.substeps"),
    (lambda c: c["profiles"]["cpu"]["scenes"]["flag"].update(frams=3), "unknown key 'frams'"),
])
def test_bad_config_is_one_clear_error(mutate, message):
    config = copy.deepcopy(CONFIG)
    mutate(config)
    with pytest.raises(PipelineError, match=message):
        validate_config(config, "cfg.yaml")


def test_key_missing_after_merge_is_named():
    config = copy.deepcopy(CONFIG)
    del config["defaults"]["solver"]["damping"]
    with pytest.raises(PipelineError, match="missing key 'damping' in scenes.flag.solver"):
        resolve_scene(config, "flag")


def test_unknown_scene_and_profile():
    with pytest.raises(PipelineError, match="unknown scene 'nope'"):
        resolve_scene(CONFIG, "nope")
    with pytest.raises(PipelineError, match="unknown profile 'gpu'"):
        resolve_scene(CONFIG, "flag", "gpu")


def test_cli_reports_bad_key_without_traceback(tmp_path):
    config = copy.deepcopy(CONFIG)
    config["scenes"]["patch"]["mesh"]["colour"] = 1
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(config))
    out = tmp_path / "s.json"
    run = subprocess.run([sys.executable, "-m", "pipeline.config", str(path), "patch", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.strip() == f"error: {path}: unknown key 'colour' in scenes.patch.mesh"
    assert not out.exists()
    with pytest.raises(PipelineError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")


def test_garment_scene_needs_no_grid_keys_and_refuses_them():
    settings = resolve_scene(CONFIG, "pants")
    assert "width" not in settings["mesh"] and "motion" not in settings["drivers"]
    config = copy.deepcopy(CONFIG)
    config["scenes"]["pants"]["mesh"]["width"] = 1.0
    with pytest.raises(PipelineError, match="key 'width' in scenes.pants.mesh applies only when generator is grid"):
        resolve_scene(config, "pants")
    config = copy.deepcopy(CONFIG)
    del config["scenes"]["flag"]["mesh"]["plane"]
    with pytest.raises(PipelineError, match="missing key 'plane' in scenes.flag.mesh"):
        resolve_scene(config, "flag")


@pytest.mark.parametrize("scene, change, message", [
    ("flag", {"physics": {"body_collision": True}}, "need a mannequin"),
    ("flag", {"dataset": {"split": "held_out"}}, "needs mannequin clips"),
    ("pants", {"network": {"conv": "EC13"}}, "network.conv 'EC13' is not among operators.conv"),
    ("pants", {"drivers": {"mannequin": {"test_clips": ["karate", "dance", "walk"]}}}, "some, but not all"),
    ("pants", {"drivers": {"mannequin": {"test_clips": ["random"]}}}, "some, but not all"),
])
def test_inconsistent_settings_are_named(scene, change, message):
    config = copy.deepcopy(CONFIG)
    config["scenes"][scene] = deep_merge(config["scenes"][scene], change)
    with pytest.raises(PipelineError, match=message):
        resolve_scene(config, scene, "paper")
