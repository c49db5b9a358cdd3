"""workflow_config.yaml: loading, schema validation and resolution of one scene's settings.

A scene's settings are `defaults` deep-merged with `scenes.<name>`, after the active profile's overlay has been
merged over the whole config. The result must hold every key the schema knows, so that each stage reads all
of its settings from one place (the resolved `settings.json` the Snakefile writes per scene). Every number must be
finite within float32's range (YAML and Python's JSON both read `.nan`/`NaN`, `.inf`/`Infinity` and 1e400 as
numbers, and the schema's `minimum` lets NaN through). settings.json may have been edited by hand, so it is
checked as strictly when it is read: numbers, the schema's types and ranges, no unknown key, every key present.
settings.json leaves out the number of sequences: it says how many sequences exist, not how any is made, so
raising it changes no input of the artifacts already made (scenes/sequences.py names the sequences).

The `settings` stage (`python -m pipeline.settings`) writes a scene's resolved settings with this module.
"""
from __future__ import annotations

import copy
import functools
import json
import os
import re
from pathlib import Path
from typing import Any, Collection, Mapping

import yaml

from model.feature_spec import FeatureSpec
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import FLOAT32_MAX, atomic_write
from scenes.sequences import clip_key, held_out_clips, is_hand, library_of, training_clips, wears_garment

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "workflow" / "config.schema.yaml"


def load_schema() -> dict:
    """The config schema, a fresh copy each call (callers build on it). Parsed once per process: resolving every
    scene reads it twice a scene, and Snakemake resolves them all at every start."""
    return copy.deepcopy(_parsed_schema())


@functools.cache
def _parsed_schema() -> dict:
    return yaml.safe_load(SCHEMA_PATH.read_text())


def load_config(path: str | os.PathLike) -> dict:
    """Read and validate a workflow config file."""
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: config file does not exist")
    try:
        config = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError) as err:
        raise PipelineError(f"{path}: cannot read the config ({err})") from None
    except yaml.YAMLError as err:
        raise PipelineError(yaml_error(path, err)) from None
    if not isinstance(config, dict):    # the schema's message would quote the whole of a file that is no config
        raise PipelineError(f"{path}: not a config (a config is YAML whose top level maps keys to values)")
    validate_config(config, str(path))
    return config


def yaml_error(path: Path, err: yaml.YAMLError) -> str:
    """One line `FILE:LINE:COLUMN: problem` for a YAML error, which PyYAML spreads over several (the offending
    text and a caret, for the problem and for the construct it interrupted)."""
    mark = getattr(err, "problem_mark", None)
    if mark is None:
        return f"{path}: not valid YAML ({' '.join(str(err).split())})"
    context, begun = getattr(err, "context", None), getattr(err, "context_mark", None)
    opened = f" ({context} at {begun.line + 1}:{begun.column + 1})" if context and begun else ""
    return f"{path}:{mark.line + 1}:{mark.column + 1}: not valid YAML: {err.problem or context}{opened}"


def validate_config(config: Any, source: str = "config") -> None:
    """Check `config` against the schema; the first problem becomes one error naming the key."""
    _validate(config, load_schema(), source)


def _validate(document: Any, schema: dict, source: str) -> None:
    """Every number finite within float32's range, then the schema; the first problem is one error."""
    import jsonschema  # here, not at the top: stages that only read resolved settings do not need it
    _check_numbers(document, source)
    validator = _whole_string_patterns(jsonschema)(schema)
    error = jsonschema.exceptions.best_match(validator.iter_errors(document))
    if error is not None:
        raise PipelineError(f"{source}: {_describe(error)}")


def _whole_string_patterns(jsonschema):
    """The draft 2020-12 validator with every `pattern` matched against the whole string. jsonschema searches
    (`re.search`), where `$` also matches before a trailing newline: "evil\\n" passed as a scene name (a folder,
    a Snakemake wildcard, a word of shell commands) and "RC9\\n" as a convolution."""
    def pattern(validator, regex, instance, schema):
        if validator.is_type(instance, "string") and re.fullmatch(regex, instance) is None:
            yield jsonschema.ValidationError(f"{instance!r} does not match {regex!r}")

    return jsonschema.validators.extend(jsonschema.Draft202012Validator, {"pattern": pattern})


# Values a config may hold once its YAML aliases are expanded (the shipped workflow_config.yaml: ~1,000). PyYAML
# builds an alias as one shared object, so ten lines of anchors each repeating the last ten times load at once,
# yet hold 10^8 values to every walk of the tree (ours below, jsonschema's): refused before any walk stalls.
MAX_CONFIG_VALUES = 100_000


def _check_numbers(document: Any, source: str) -> None:
    """Every number finite within float32's range (where the solver and the network compute), the first that is
    not one error naming its dotted key; a document of more than MAX_CONFIG_VALUES values one error. Iterative,
    depth first in document order, counting values as they are reached: nesting is bounded by memory rather than
    the stack, and the count by the limit however wide each level."""
    pending: list[tuple[tuple[str, ...], Any]] = [((), document)]
    reached = 1
    while pending:
        where, value = pending.pop()
        if isinstance(value, (dict, list)):
            reached += len(value)
            if reached > MAX_CONFIG_VALUES:
                raise PipelineError(f"{source}: more than {MAX_CONFIG_VALUES:,} values once YAML aliases are "
                                    f"expanded (an alias repeating another many times over?)")
            items = value.items() if isinstance(value, dict) else enumerate(value)
            pending += reversed([((*where, str(key)), item) for key, item in items])
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and not abs(value) <= FLOAT32_MAX:
            raise PipelineError(f"{source}: {'.'.join(where) or 'top level'}: {value!r} is not a finite number "
                                f"within float32's range")


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
    settings = deep_merge(merged["defaults"], _scene_block(merged["scenes"], scene, source))
    _require_complete(settings, load_schema()["$defs"]["scene_settings"], f"scenes.{scene}", source,
                      hint=" (set it there or in defaults)")
    _check_consistent(settings, f"scenes.{scene}", source)
    settings.update(scene=scene, profile=profile, device=device or merged["device"])
    return settings


def _scene_block(scenes: dict, scene: str, source: str) -> dict:
    """`scenes.<scene>` (the profile's overlay merged in), over the scene it is `like` less that scene's mesh: a
    scene of another mesh takes everything else of its base, profile overlays included."""
    block = scenes[scene]
    like = block.get("like")
    if like is None:
        return block
    if like not in scenes or like == scene or "like" in scenes[like]:
        raise PipelineError(f"{source}: scenes.{scene}.like: '{like}' is not another scene of the config without a "
                            f"`like` of its own (known: {', '.join(sorted(s for s in scenes if s != scene))})")
    base = {key: value for key, value in scenes[like].items() if key != "mesh"}
    return deep_merge(base, {key: value for key, value in block.items() if key != "like"})


def _require_complete(settings: dict, schema: dict, where: str | None, source: str, hint: str = "",
                      optional: Collection[str] = ()) -> None:
    """Every key the schema knows must be set, except those `x-required-when` reserves for other cases (a grid
    scene needs no garment, a garment scene no rod motion), those the schema's `x-optional` lists (a key whose
    absence has a meaning: `solver.kind` absent is xpbd) and, at this level, `optional`; a key of another case
    is an error, not ignored. `where` names this level in messages (None: the top level); `hint` ends the
    message of a missing key."""
    conditional = schema.get("x-required-when")
    needed = set(schema.get("properties", {})) - set(optional) - set(schema.get("x-optional", ()))
    foreign: set[str] = set()
    if conditional:
        cases = conditional["cases"]
        case = settings.get(conditional["key"])
        reserved = {key for keys in cases.values() for key in keys}
        needed -= reserved - set(cases.get(case, ()))
        foreign = (reserved - set(cases.get(case, ()))) & set(settings)
    if foreign:
        key = sorted(foreign)[0]
        owners = [c for c, keys in conditional["cases"].items() if key in keys]
        raise PipelineError(f"{source}: key '{key}' in {where or 'top level'} applies only when "
                            f"{conditional['key']} is {' or '.join(owners)} (here: {settings.get(conditional['key'])})")
    for key, sub in schema.get("properties", {}).items():
        if key not in needed:
            continue
        if key not in settings:
            raise PipelineError(f"{source}: missing key '{key}' in {where or 'top level'}{hint}")
        if sub.get("type") == "object" and "properties" in sub:
            _require_complete(settings[key], sub, f"{where}.{key}" if where else key, source, hint)


def _check_consistent(settings: dict, where: str, source: str) -> None:
    """Rules between keys that a schema cannot state."""
    def fail(message: str):
        raise PipelineError(f"{source}: {where}: {message}")
    generator = settings["mesh"]["generator"]
    garment, hand = wears_garment(settings), is_hand(settings)
    if garment != (settings["drivers"]["pins"] == "attachment"):
        fail("drivers.pins must be 'attachment' exactly when mesh.generator is 'garment' or 'garment_file'")
    if hand != (settings["drivers"]["pins"] == "bones"):
        fail("drivers.pins must be 'bones' exactly when mesh.generator is 'hand' or 'hand_file'")
    if hand != (settings["solver"].get("kind") == "fem"):
        fail("solver.kind must be 'fem' exactly when mesh.generator is 'hand' or 'hand_file' (the volumetric FEM moves "
             "the hand)")
    if "fem" in settings["solver"] and not hand:
        fail("solver.fem applies only to solver.kind 'fem'")
    if hand:
        drive = settings["drivers"]["hand"]
        if drive["min_interval"] > drive["max_interval"]:
            fail(f"drivers.hand.min_interval {drive['min_interval']} is more than max_interval "
                 f"{drive['max_interval']}")
    if not garment and (settings["physics"]["body_collision"] or settings["dataset"]["frame"] == "torso"):
        fail("physics.body_collision and dataset.frame 'torso' need a mannequin (mesh.generator 'garment' or 'garment_file')")
    if settings["network"]["conv"] not in settings["operators"]["conv"]:
        fail(f"network.conv '{settings['network']['conv']}' is not among operators.conv "
             f"{settings['operators']['conv']}")
    feature_spec(settings["network"], garment, f"{source}: {where}: network")
    if not garment and settings["study"]["sequence_counts"] != [1]:
        fail("study.sequence_counts: a grid scene has one sequence, so its study can only count [1]")
    for variant, inputs in settings["study"]["variants"].items():
        feature_spec(inputs, garment, f"{source}: {where}: study.variants.{variant}")
    for name, application in settings["applications"].items():
        merged = deep_merge({key: settings[key] for key in ("network", "operators")},
                            {key: application[key] for key in ("network", "operators") if key in application})
        if "U" != merged["network"]["arch"].strip()[:1]:
            fail(f"applications.{name}.network.arch '{merged['network']['arch']}': the network of an "
                 f"application is a decoder, written with U tokens")
        if merged["network"]["conv"] not in merged["operators"]["conv"]:
            fail(f"applications.{name}: network.conv '{merged['network']['conv']}' is not among its operators.conv "
                 f"{merged['operators']['conv']}")
    if generator == "grid" and settings["sequences"] != 1:
        fail(f"sequences {settings['sequences']}: a grid scene has one sequence (its rod's motion)")
    if hand and settings["sequences"] < 1:
        fail("sequences 0: the hand needs training sequences")
    library = library_of(settings)
    if garment and settings["sequences"] == 0 and library is None:
        fail("sequences 0: a garment scene without a motion library (drivers.mannequin.library) needs training "
             "sequences")
    held_subjects = settings["library_windows"]["held_out_subjects"]
    if held_subjects and (library is None or settings["dataset"]["split"] != "held_out"):
        fail("library_windows.held_out_subjects needs drivers.mannequin.library and dataset.split 'held_out'")
    if settings["dataset"]["split"] == "held_out":
        if not (garment or hand):
            fail("dataset.split 'held_out' needs mannequin clips or hand motions (mesh.generator 'garment', "
                 "'garment_file', 'hand' or 'hand_file')")
        if not held_out_clips(settings) and not held_subjects:
            fail("dataset.split 'held_out' needs drivers.mannequin.test_clips, drivers.hand.test_motions or "
                 "library_windows.held_out_subjects")
        if garment and settings["sequences"] and not training_clips(settings):
            fail(f"drivers.mannequin.clips {_names(settings['drivers']['mannequin']['clips'])} are all held out "
                 f"(test_clips): training sequences need at least one other")
    if garment:
        mannequin = settings["drivers"]["mannequin"]
        for entry in mannequin["clips"] + mannequin["test_clips"]:
            if isinstance(entry, dict) and entry.get("start", 0.0) >= entry.get("end", float("inf")):
                fail(f"BVH clip {entry['bvh']}: start {entry['start']} must come before end {entry['end']}")


def feature_spec(network: Mapping[str, Any], has_body: bool, where: str) -> FeatureSpec:
    """The per-vertex inputs that `network`'s keys inputs, input_frame, output_frame and frame_tangent name (a
    scene's `network.*`, a study variant, or train's flags: `inputs` a list, or comma-separated as the --inputs
    flag spells it), checked the same way wherever they are read: FeatureSpec's own checks (names, frames), and
    input 'body' only where the scene has a mannequin (`has_body`). One error naming `where` otherwise."""
    inputs = network["inputs"]
    try:
        features = FeatureSpec(tuple(inputs.split(",") if isinstance(inputs, str) else inputs),
                               network["input_frame"], network["output_frame"], network["frame_tangent"])
    except ValueError as err:
        raise PipelineError(f"{where}: {err}") from None
    if "body" in features.inputs and not has_body:
        raise PipelineError(f"{where}: input 'body' measures the cloth against the mannequin's capsules, and this "
                            f"scene has no mannequin (mesh.generator 'garment' and 'garment_file' have one)")
    return features


def _names(entries: list) -> str:
    """Clip entries as a short list for messages (kinds and BVH windows)."""
    return "[" + ", ".join(clip_key(entry) for entry in entries) + "]"


# Read by the workflow only, never by a stage: kept out of settings.json, so that changing them reruns no stage
# of the scene (more sequences add jobs; the study's grid adds study jobs; an application's settings go into its
# own settings.json, `application_settings`).
WORKFLOW_ONLY = ("sequences", "library_windows", "shard", "study", "applications", "tradeoff", "convs")


def shared_settings(settings: dict) -> dict:
    """What settings.json holds: the resolved settings without what only the workflow reads (WORKFLOW_ONLY)."""
    return {key: value for key, value in settings.items() if key not in WORKFLOW_ONLY}


# Read by the learning stages only (operators, train, evaluate): kept out of simulation.json, which the stages
# that make the motion and the cloth (scene, subdivide, simulate) read, so that a change of the network or its
# training reruns no simulation. (`dataset` stays: its `split` decides which clips the training sequences use.)
LEARNING_ONLY = ("operators", "network", "training", "evaluation")


def simulation_settings(settings: dict) -> dict:
    """What simulation.json holds: settings.json's content less what only the learning stages read."""
    return {key: value for key, value in shared_settings(settings).items() if key not in LEARNING_ONLY}


def application_settings(settings: dict, name: str) -> dict:
    """What results/<scene>/<name>/settings.json holds for application `name` (pose, pca): the scene's
    settings.json with `applications.<name>` (less its PCA component counts, which name folders) merged over
    it, so that its stages read their flags from it as the upsampling's read the scene's."""
    overlay = {key: value for key, value in settings["applications"][name].items() if key != "components"}
    return deep_merge(shared_settings(settings), overlay)


def write_settings(settings: dict, path: str | os.PathLike) -> None:
    """Write resolved settings as JSON, through the one safe-write helper (pipeline.core.h5.atomic_write)."""
    with atomic_write(path) as f:
        f.write(json.dumps(settings, indent=2, sort_keys=True, allow_nan=False).encode())


def read_settings(path: str | os.PathLike, unread: tuple[str, ...] = ()) -> dict:
    """Settings written by `write_settings` (the per-scene settings.json or simulation.json), checked as
    `resolve_scene` checks a scene's: `load_settings`, then every key present but the top-level `unread` ones the
    reading stage never uses (a hand-edited file without `solver.substeps` would otherwise run with the solver's
    own default)."""
    settings = load_settings(path)
    require_complete_settings(settings, path, unread)
    return settings


def load_settings(path: str | os.PathLike) -> dict:
    """A settings.json whose present keys are checked: finite numbers, the schema's types and ranges, no unknown
    key; `require_complete_settings` checks that none is missing."""
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: settings file does not exist")
    try:
        settings = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as err:
        raise PipelineError(f"{path}: cannot read the settings ({err})") from None
    except json.JSONDecodeError as err:
        raise PipelineError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(settings, dict):
        raise PipelineError(f"{path}: not a JSON object of settings")
    _validate(settings, _settings_schema(), str(path))
    return settings


def require_complete_settings(settings: dict, path: str | os.PathLike, unread: tuple[str, ...] = ()) -> None:
    """Every key of a scene's settings.json is present (those only the workflow reads, and the top-level `unread`
    ones, may be left out)."""
    _require_complete(settings, _settings_schema(), None, str(path), optional=WORKFLOW_ONLY + tuple(unread))


def _settings_schema() -> dict:
    """The schema of settings.json: a scene's settings (WORKFLOW_ONLY keys allowed, not needed) and the scene's
    name, profile and device, which `resolve_scene` adds."""
    schema = load_schema()
    scene = schema["$defs"]["scene_settings"]
    name = {"type": "string", **schema["properties"]["scenes"]["propertyNames"]}
    return {"$defs": schema["$defs"], **scene,
            "properties": {**scene["properties"], "scene": name, "profile": schema["properties"]["profile"],
                           "device": schema["properties"]["device"]}}
