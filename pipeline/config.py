"""workflow_config.yaml: loading, schema validation and resolution of one scene's settings.

A scene's settings are `defaults` deep-merged with `scenes.<name>`, after the active profile's overlay has been
merged over the whole config. The result must hold every key the schema knows, so that each stage reads all
of its settings from one place (the resolved `settings.json` the Snakefile writes per scene). settings.json
leaves out the number of sequences: it says how many sequences exist, not how any is made, so raising it changes
no input of the artifacts already made (scenes/sequences.py names the sequences).

CLI: `python -m pipeline.config CONFIG.yaml SCENE OUT.json [--profile P] [--device D]` writes resolved settings
(as settings.json holds them) and prints the scene's sequence names.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Sequence

import yaml

from pipeline.errors import PipelineError
from scenes.sequences import clip_key, held_out_clips, sequence_names, training_clips

SCHEMA_PATH = Path(__file__).resolve().parent.parent / "workflow" / "config.schema.yaml"


def load_schema() -> dict:
    return yaml.safe_load(SCHEMA_PATH.read_text())


def load_config(path: str | os.PathLike) -> dict:
    """Read and validate a workflow config file."""
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: config file does not exist")
    try:
        config = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise PipelineError(f"{path}: not valid YAML ({err})") from None
    validate_config(config, str(path))
    return config


def validate_config(config: Any, source: str = "config") -> None:
    """Check `config` against the schema; the first problem becomes one error naming the key."""
    import jsonschema  # here, not at the top: stages that only read resolved settings do not need it
    validator = jsonschema.Draft202012Validator(load_schema())
    error = jsonschema.exceptions.best_match(validator.iter_errors(config))
    if error is not None:
        raise PipelineError(f"{source}: {_describe(error)}")


def _describe(error) -> str:
    """One line for a jsonschema.ValidationError."""
    where = ".".join(str(p) for p in error.absolute_path) or "top level"
    if error.validator == "additionalProperties":
        patterns = [re.compile(p) for p in error.schema.get("patternProperties", {})]
        unknown = sorted(key for key in set(error.instance) - set(error.schema.get("properties", {}))
                         if not any(p.search(key) for p in patterns))
        if unknown:
            return f"unknown key '{unknown[0]}' in {where}"
    if error.validator == "oneOf" and "description" in error.schema:     # say what would do, not which failed
        return f"{where}: {error.instance!r} is not {error.schema['description']}"
    if error.validator == "required":
        missing = [k for k in error.validator_value if k not in error.instance]
        return f"missing key '{missing[0]}' in {where}"
    return f"{where}: {error.message}"


def deep_merge(base: dict, overlay: dict) -> dict:
    """A copy of `base` with `overlay` merged in; nested dicts merge, anything else is replaced."""
    merged = copy.deepcopy(base)
    for key, value in overlay.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def resolve_scene(config: dict, scene: str, profile: str | None = None, device: str | None = None,
                  source: str = "config") -> dict:
    """The complete settings of `scene`: profile overlay, then defaults + scene. Adds `scene`, `profile`,
    `device`. Raises PipelineError for an unknown scene or profile, or a key missing after the merge."""
    validate_config(config, source)
    profile = profile or config["profile"]
    overlays = config.get("profiles", {})
    if profile not in overlays:
        raise PipelineError(f"{source}: unknown profile '{profile}' (known: {', '.join(sorted(overlays)) or 'none'})")
    merged = deep_merge({k: v for k, v in config.items() if k != "profiles"}, overlays[profile])
    if scene not in merged["scenes"]:
        raise PipelineError(f"{source}: unknown scene '{scene}' (known: {', '.join(sorted(merged['scenes']))})")
    settings = deep_merge(merged["defaults"], merged["scenes"][scene])
    _require_complete(settings, load_schema()["$defs"]["scene_settings"], f"scenes.{scene}", source)
    _check_consistent(settings, f"scenes.{scene}", source)
    settings.update(scene=scene, profile=profile, device=device or merged["device"])
    return settings


def _require_complete(settings: dict, schema: dict, where: str, source: str) -> None:
    """Every key the schema knows must be set, except those `x-required-when` reserves for other cases (a grid
    scene needs no garment, a garment scene no rod motion); a key of another case is an error, not ignored."""
    conditional = schema.get("x-required-when")
    needed, foreign = set(schema.get("properties", {})), set()
    if conditional:
        cases = conditional["cases"]
        case = settings.get(conditional["key"])
        reserved = {key for keys in cases.values() for key in keys}
        needed -= reserved - set(cases.get(case, ()))
        foreign = (reserved - set(cases.get(case, ()))) & set(settings)
    if foreign:
        key = sorted(foreign)[0]
        owners = [c for c, keys in conditional["cases"].items() if key in keys]
        raise PipelineError(f"{source}: key '{key}' in {where} applies only when {conditional['key']} is "
                            f"{' or '.join(owners)} (here: {settings.get(conditional['key'])})")
    for key, sub in schema.get("properties", {}).items():
        if key not in needed:
            continue
        if key not in settings:
            raise PipelineError(f"{source}: missing key '{key}' in {where} (set it there or in defaults)")
        if sub.get("type") == "object" and "properties" in sub:
            _require_complete(settings[key], sub, f"{where}.{key}", source)


def _check_consistent(settings: dict, where: str, source: str) -> None:
    """Rules between keys that a schema cannot state."""
    def fail(message: str):
        raise PipelineError(f"{source}: {where}: {message}")
    garment = settings["mesh"]["generator"] == "garment"
    if garment != (settings["drivers"]["pins"] == "attachment"):
        fail("drivers.pins must be 'attachment' exactly when mesh.generator is 'garment'")
    if not garment and (settings["physics"]["body_collision"] or settings["dataset"]["frame"] == "torso"):
        fail("physics.body_collision and dataset.frame 'torso' need a mannequin (mesh.generator 'garment')")
    if settings["network"]["conv"] not in settings["operators"]["conv"]:
        fail(f"network.conv '{settings['network']['conv']}' is not among operators.conv "
             f"{settings['operators']['conv']}")
    if not garment and settings["sequences"] != 1:
        fail(f"sequences {settings['sequences']}: a grid scene has one sequence (its rod's motion)")
    if settings["dataset"]["split"] == "held_out":
        if not garment:
            fail("dataset.split 'held_out' needs mannequin clips (mesh.generator 'garment')")
        if not held_out_clips(settings):
            fail("dataset.split 'held_out' needs drivers.mannequin.test_clips")
        if not training_clips(settings):
            fail(f"drivers.mannequin.clips {_names(settings['drivers']['mannequin']['clips'])} are all held out "
                 f"(test_clips): training sequences need at least one other")
    if garment:
        mannequin = settings["drivers"]["mannequin"]
        for entry in mannequin["clips"] + mannequin["test_clips"]:
            if isinstance(entry, dict) and entry.get("start", 0.0) >= entry.get("end", float("inf")):
                fail(f"BVH clip {entry['bvh']}: start {entry['start']} must come before end {entry['end']}")


def _names(entries: list) -> str:
    """Clip entries as a short list for messages (kinds and BVH windows)."""
    return "[" + ", ".join(clip_key(entry) for entry in entries) + "]"


def shared_settings(settings: dict) -> dict:
    """What settings.json holds: the resolved settings without the number of sequences (see the module
    docstring)."""
    return {key: value for key, value in settings.items() if key != "sequences"}


def write_settings(settings: dict, path: str | os.PathLike) -> None:
    """Write resolved settings as JSON, atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        json.dump(settings, f, indent=2, sort_keys=True)
    os.replace(tmp, path)


def read_settings(path: str | os.PathLike) -> dict:
    """Settings written by `write_settings` (the per-scene settings.json)."""
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: settings file does not exist")
    try:
        settings = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise PipelineError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(settings, dict):
        raise PipelineError(f"{path}: not a JSON object of settings")
    return settings


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.config", description=__doc__.splitlines()[0])
    parser.add_argument("config", help="workflow_config.yaml")
    parser.add_argument("scene")
    parser.add_argument("out", help="resolved settings (JSON)")
    parser.add_argument("--profile", help="overlay to apply (default: the config's `profile`)")
    parser.add_argument("--device", help="override the device (cpu, cuda:0)")
    args = parser.parse_args(argv)
    config = load_config(args.config)
    settings = resolve_scene(config, args.scene, args.profile, args.device, args.config)
    write_settings(shared_settings(settings), args.out)
    print(" ".join(sequence_names(settings)))


if __name__ == "__main__":
    from pipeline import cli  # here: pipeline.cli reads settings through this module

    cli.run(main)
