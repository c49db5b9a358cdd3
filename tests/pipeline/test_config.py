"""workflow_config.yaml: schema validation, profile overlays, clear errors; resolved settings as the defaults of
a stage's flags."""
import argparse
import copy
import subprocess
import sys

import pytest
import yaml

from pipeline.core.cli import parse_with_settings
from pipeline.core.config import (LEARNING_ONLY, deep_merge, load_config, load_schema, read_settings, resolve_scene,
                                  shared_settings, simulation_settings, validate_config, write_settings)
from pipeline.core.errors import PipelineError
from scenes.motion import MOTION_KINDS

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
    run = subprocess.run([sys.executable, "-m", "pipeline.settings", str(path), "patch", str(out)],
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
    ("pants", {"drivers": {"mannequin": {"test_clips": ["karate", "dance", "walk", "random"]}}}, "are all held out"),
    ("pants", {"drivers": {"mannequin": {"test_clips": []}}}, "needs drivers.mannequin.test_clips"),
    ("pants", {"drivers": {"mannequin": {"test_clips": [{"bvh": "a.bvh", "start": 2, "end": 1.5}]}}},
     "BVH clip a.bvh: start 2 must come before end 1.5"),
    ("flag", {"sequences": 2}, "a grid scene has one sequence"),
    ("hand", {"solver": {"kind": "xpbd"}}, "solver.kind must be 'fem' exactly when mesh.generator is 'hand'"),
    ("pants", {"solver": {"kind": "fem"}}, "solver.kind must be 'fem' exactly when mesh.generator is 'hand'"),
    ("flag", {"solver": {"fem": {"poisson_ratio": 0.3}}}, "solver.fem applies only to solver.kind 'fem'"),
    ("hand", {"drivers": {"hand": {"min_interval": 2.0}}}, "min_interval 2.0 is more than max_interval 1.2"),
    ("hand", {"drivers": {"hand": {"test_motions": []}}}, "needs drivers.mannequin.test_clips, drivers.hand.test"),
    ("hand", {"sequences": 0}, "the hand needs training sequences"),
    ("hand", {"mesh": {"max_edge": 0.1}}, "key 'max_edge' in scenes.hand.mesh applies only when generator is grid"),
    ("hand", {"mesh": {"generator": "hand_file", "file": "h.obj", "units": "auto"}},
     "key 'skin_spacing' in scenes.hand.mesh applies only when generator is hand \\(here: hand_file\\)"),
])
def test_inconsistent_settings_are_named(scene, change, message):
    config = copy.deepcopy(CONFIG)
    config["scenes"][scene] = deep_merge(config["scenes"][scene], change)
    with pytest.raises(PipelineError, match=message):
        resolve_scene(config, scene, "paper")


def test_a_users_hand_is_the_hand_scene_but_its_mesh_and_needs_its_bone_file():
    config = copy.deepcopy(CONFIG)
    mesh = {"generator": "hand_file", "file": "h.obj", "bones": "b.yaml", "units": "cm", "tet_spacing": 0.008}
    config["scenes"]["mine"] = {"like": "hand", "mesh": mesh}
    settings, hand = resolve_scene(config, "mine", "cpu"), resolve_scene(config, "hand", "cpu")
    assert settings["mesh"].items() >= mesh.items() and settings["solver"] == hand["solver"] and settings["frames"] == hand["frames"]
    config["scenes"]["mine"]["mesh"] = {k: v for k, v in mesh.items() if k != "bones"}
    with pytest.raises(PipelineError, match="missing key 'bones' in scenes.mine.mesh"):
        resolve_scene(config, "mine", "cpu")


@pytest.mark.parametrize("entry, message", [
    ({"start": 1.0}, "missing key 'bvh'"),
    ({"bvh": "a.bvh", "stop": 1.0}, "unknown key 'stop'"),
    ({"bvh": "a.bvh", "start": -1.0}, "test_clips.0"),
    ("moonwalk", r"test_clips.0: 'moonwalk' is not a procedural motion kind \(rest, walk"),
])
def test_a_bad_clip_entry_is_named(entry, message):
    config = copy.deepcopy(CONFIG)
    config["scenes"]["pants"]["drivers"]["mannequin"]["test_clips"] = [entry]
    with pytest.raises(PipelineError, match=message):
        validate_config(config, "cfg.yaml")


def test_clips_may_be_bvh_windows_and_held_out_clips_need_not_be_trained_clips():
    config = copy.deepcopy(CONFIG)
    config["scenes"]["pants"]["drivers"]["mannequin"].update(
        clips=["dance", {"bvh": "mocap/a.bvh"}], test_clips=[{"bvh": "mocap/walk.bvh", "start": 4.5, "end": 7}])
    settings = resolve_scene(config, "pants", "cpu")
    assert settings["drivers"]["mannequin"]["test_clips"] == [{"bvh": "mocap/walk.bvh", "start": 4.5, "end": 7}]


def test_settings_json_holds_no_sequence_count():
    """Raising the number of sequences must leave settings.json, the input of every artifact, as it was."""
    config = copy.deepcopy(CONFIG)
    few = resolve_scene(config, "pants", "cpu")
    config["profiles"]["cpu"]["scenes"]["pants"]["sequences"] = 17
    many = resolve_scene(config, "pants", "cpu")
    assert (few["sequences"], many["sequences"]) != (17, 17) and many["sequences"] == 17
    assert shared_settings(few) == shared_settings(many) and "sequences" not in shared_settings(many)


def test_cli_writes_the_shared_settings_and_names_the_sequences(tmp_path):
    run = subprocess.run([sys.executable, "-m", "pipeline.settings", "workflow_config.yaml", "pants",
                          str(tmp_path / "s.json")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    cpu = resolve_scene(CONFIG, "pants", "cpu")
    assert run.stdout.split() == [f"train_{i:03d}" for i in range(cpu["sequences"])] + ["held_out_000"]
    assert "sequences" not in (tmp_path / "s.json").read_text()


def _stage_parser() -> argparse.ArgumentParser:
    """Flags of the kinds the stages have: typed, a comma-joined list, a required one, one without a setting."""
    parser = argparse.ArgumentParser(prog="stage")
    parser.add_argument("out")
    parser.add_argument("--width", type=float, default=1.0)
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--conv", default="RC13")
    parser.add_argument("--test-clips")
    parser.add_argument("--threads", type=int)
    return parser


def _flags(settings: dict) -> dict:
    return {"width": settings["network"]["width"], "epochs": settings["training"]["epochs"],
            "conv": settings["operators"]["conv"], "test_clips": settings["drivers"]["mannequin"]["test_clips"]}


def test_settings_are_the_defaults_of_the_flags_with_their_types(tmp_path):
    settings = resolve_scene(CONFIG, "pants", "cpu")
    settings["network"]["width"] = 1            # an integer in YAML: the flag still makes a float of it
    settings["operators"]["conv"] = ["RC9", "EC9"]
    write_settings(settings, tmp_path / "s.json")
    args = parse_with_settings(_stage_parser(), ["o.h5", "--settings", str(tmp_path / "s.json")], _flags)
    assert vars(args) == {"out": "o.h5", "width": 1.0, "epochs": settings["training"]["epochs"], "conv": "RC9,EC9",
                          "test_clips": "walk", "threads": None}
    assert type(args.width) is float and type(args.epochs) is int


def test_a_flag_given_by_hand_overrides_its_setting(tmp_path):
    write_settings(resolve_scene(CONFIG, "pants", "cpu"), tmp_path / "s.json")
    args = parse_with_settings(_stage_parser(), ["--epochs", "3", "--settings", str(tmp_path / "s.json"), "o.h5",
                                                 "--width=0.5", "--threads", "2"], _flags)
    assert (args.epochs, args.width, args.threads, args.test_clips) == (3, 0.5, 2, "walk")


def test_without_settings_the_flags_keep_their_own_defaults():
    args = parse_with_settings(_stage_parser(), ["o.h5"], _flags)
    assert vars(args) == {"out": "o.h5", "width": 1.0, "epochs": 200, "conv": "RC13", "test_clips": None,
                          "threads": None}


@pytest.mark.parametrize("content, message", [
    (None, "settings file does not exist"),
    ("{not json", "not valid JSON"),
    ('{"network": {"width": 1}}', "missing setting 'training'"),
    ('{"network": 1, "training": {}}', "network: 1 is not of type 'object'"),
    ("[1, 2]", "not a JSON object of settings"),
])
def test_bad_settings_file_is_one_clear_error(tmp_path, content, message):
    path = tmp_path / "s.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(PipelineError, match=message) as error:
        parse_with_settings(_stage_parser(), ["o.h5", "--settings", str(path)], _flags)
    assert str(error.value).startswith(f"{path}: ")


def test_simulation_json_leaves_out_what_only_learning_reads_and_the_data_stages_accept_it(tmp_path):
    """simulation.json (what scene, subdivide, simulate and dataset read) is settings.json less the network, its
    operators, training and evaluation, so a training change does not touch it; `dataset.split` stays (it picks
    the training sequences' clips). The learning stages' full check refuses it; the data stages' accepts it."""
    settings = resolve_scene(CONFIG, "pants")
    simulation = simulation_settings(settings)
    assert set(shared_settings(settings)) - set(simulation) == set(LEARNING_ONLY)
    assert simulation["dataset"] == settings["dataset"]
    retrained = resolve_scene(CONFIG, "pants")
    retrained["training"] = {**retrained["training"], "epochs": 99}
    assert simulation_settings(retrained) == simulation
    write_settings(simulation, tmp_path / "simulation.json")
    assert read_settings(tmp_path / "simulation.json", unread=LEARNING_ONLY) == simulation
    with pytest.raises(PipelineError, match="missing key 'operators' in top level"):
        read_settings(tmp_path / "simulation.json")


def test_the_schema_names_every_procedural_motion_kind():
    """The schema's clip enum is written by hand: a kind added to scenes.motion must be added there too."""
    clip = load_schema()["$defs"]["clip"]
    assert [set(option["enum"]) for option in clip["oneOf"] if "enum" in option] == [set(MOTION_KINDS)]
