"""The operator comparison's grid as the workflow lays it out (workflow/rules/convs.smk, `results/<scene>/convs/`):
from a scene's name and resolved settings, its tasks (the upsampling, and the pose decoder where the scene has a
mannequin), the convolutions (`convs.kinds` x `convs.lengths`), each task's architectures with `x` resolved, the
seeds, every run's folder, the settings its jobs read and the `experiments.convs` stage's arguments.

Architectures: `scene` is the scene's own network.arch; any other entry of `convs.archs` is a template in the
paper's notation with channel counts as multiples of x (`Dx D2x D4x D_5 D4x`, the paper's D^x D^2x D^4x D_5 D^4x),
and x is the smallest whole number whose network, at the scene's width, has the parameter count nearest the
scene's own network at the same filter length: the paper's supplementary Table 2 compares architectures of (about)
one size so. The pose decoder's count depends on the mesh (its fully connected layer), so its one architecture is
the pose application's. The Snakefile imports this at every start: it reads settings only and imports nothing heavy
(the counts are arithmetic on the architecture string, docs/architecture.md "Why this wiring").
"""
from __future__ import annotations

import re
from typing import Any

from model.architecture import Architecture, parse_architecture
from model.feature_spec import FEATURE_CHANNELS
from pipeline.core.config import application_settings, deep_merge, shared_settings
from pipeline.core.errors import PipelineError

Settings = dict[str, Any]
UPSAMPLING, POSE = "upsampling", "pose"
SCENE_ARCH = "scene"
OUT_CHANNELS = 3                  # a displacement per vertex
X_MAX = 4096                      # the widest x searched (the paper's largest is 80)
_TEMPLATE_TOKEN = re.compile(r"^D(?P<times>[1-9][0-9]*)?x(?P<repeat>_[1-9][0-9]*)?$")


def tasks(settings: Settings) -> list[str]:
    """The upsampling, then the pose decoder where `convs.pose` asks for it and the scene has a mannequin."""
    has_pose = settings["convs"]["pose"] and settings["mesh"]["generator"] == "garment"
    return [UPSAMPLING, *([POSE] if has_pose else [])]


def conv_names(settings: Settings) -> list[str]:
    """Every convolution of the grid, by length then kind in config order: RC9, EC9, ..., SPD13."""
    convs = settings["convs"]
    return [f"{kind}{length}" for length in convs["lengths"] for kind in convs["kinds"]]


def conv_length(conv: str) -> int:
    return int(re.sub(r"^[A-Z]+", "", conv))


def seeds(settings: Settings) -> list[int]:
    return list(settings["convs"]["seeds"])


def arch_labels(settings: Settings, task: str) -> list[str]:
    """Folder names of a task's architectures: a<k>, the k-th of `convs.archs` (the pose decoder has a0 only)."""
    return [f"a{k}" for k in range(len(settings["convs"]["archs"]) if task == UPSAMPLING else 1)]


def encoder_decoder_parameters(arch: Architecture, length: int, in_channels: int,
                               out_channels: int = OUT_CHANNELS) -> int:
    """Learnable parameters of model.networks.EncoderDecoder (docs/architecture.md, "Encoder-decoder wiring"): a
    convolution of C_in -> C_out channels has length * C_in * C_out weights and C_out biases; the encoder convolves
    into each DownConv's channels, every DownConv but the bottleneck has an UpConv (conv from the level below, then
    conv of the concatenated skip, 2h -> h), and a head h -> out -> out; norms have no parameters."""
    convs: list[tuple[int, int]] = []
    channels = in_channels
    down = [h for h in arch.blocks if h is not None]
    for h in down:
        convs.append((channels, h))
        channels = h
    for h in reversed(down[:-1]):
        convs += [(channels, h), (2 * h, h)]
        channels = h
    convs += [(channels, out_channels), (out_channels, out_channels)]
    return sum(length * c_in * c_out + c_out for c_in, c_out in convs)


def in_channels(settings: Settings) -> int:
    """The upsampling network's per-vertex input channels (network.inputs)."""
    return sum(FEATURE_CHANNELS[name] for name in settings["network"]["inputs"])


def _parse_template(template: str) -> list[tuple[int | None, str]]:
    """A template's tokens: (multiple of x, repeat suffix) for a DownConv in x, (None, token) for any other."""
    tokens = template.split()
    if not any(_TEMPLATE_TOKEN.match(token) for token in tokens):
        raise PipelineError(f"workflow config: convs.archs: '{template}' has no channel count in x (e.g. "
                            f"'Dx D2x D4x D_5 D4x'): write the scene's own as 'scene'")
    return [(int(m["times"] or 1), m["repeat"] or "") if (m := _TEMPLATE_TOKEN.match(token)) else (None, token)
            for token in tokens]


def instantiate(template: str, x: int) -> str:
    """The template with its channel counts in x made numbers: ('Dx D2x D_5 D4x', 80) -> 'D80 D160 D_5 D320'."""
    return " ".join(token if times is None else f"D{times * x}{token}" for times, token in _parse_template(template))


def _parsed(text: str, where: str) -> Architecture:
    try:
        return parse_architecture(text, "D")
    except ValueError as err:
        raise PipelineError(f"workflow config: {where}: {err}") from None


def resolve_template(template: str, target: int, length: int, width: float, channels: int) -> tuple[str, int]:
    """(arch, parameters): the smallest x whose network at `width` has the count nearest `target`."""
    best: tuple[int, int, str] | None = None
    for x in range(1, X_MAX + 1):
        arch = instantiate(template, x)
        count = encoder_decoder_parameters(_parsed(arch, f"convs.archs '{template}'").scaled(width), length, channels)
        if best is None or abs(count - target) < best[0]:
            best = (abs(count - target), count, arch)
        if count > target:      # the count grows with x: past the target nothing comes nearer
            break
    return best[2], best[1]


def architecture(settings: Settings, task: str, label: str, conv: str) -> str:
    """The architecture string of run folder `label` of `task` at convolution `conv`."""
    if task == POSE:
        return application_settings(settings, POSE)["network"]["arch"]
    entry = settings["convs"]["archs"][int(label[1:])]
    scene_arch = settings["network"]["arch"]
    if entry == SCENE_ARCH:
        return scene_arch
    width, length, channels = settings["network"]["width"], conv_length(conv), in_channels(settings)
    target = encoder_decoder_parameters(_parsed(scene_arch, "network.arch").scaled(width), length, channels)
    return resolve_template(entry, target, length, width, channels)[0]


def run_folder(scene: str, task: str, label: str, conv: str, seed: int | str) -> str:
    return f"results/{scene}/convs/{task}/{label}/{conv}/s{seed}"


def runs(scene: str, settings: Settings) -> list[tuple[str, int, str, str]]:
    """(task, seed, eval.h5, train.h5) of every run, by task, architecture, convolution and seed."""
    return [(task, seed, f"{folder}/eval.h5", f"{folder}/train.h5")
            for task in tasks(settings) for label in arch_labels(settings, task)
            for conv in conv_names(settings) for seed in seeds(settings)
            for folder in [run_folder(scene, task, label, conv, seed)]]


def stage_arguments(scene: str, settings: Settings) -> list[str]:
    """`--run TASK SEED EVAL.h5 TRAIN.h5` for each run, `--part CONVS.h5` for each of `convs.parts`."""
    return [str(word) for run in runs(scene, settings) for word in ("--run", *run)] + [
        word for part in settings["convs"]["parts"] for word in ("--part", part)]


def stage_inputs(scene: str, settings: Settings) -> list[str]:
    return [path for _, _, evaluation, train_log in runs(scene, settings) for path in (evaluation, train_log)] + [
        *settings["convs"]["parts"]]


def task_dataset(scene: str, task: str) -> str:
    """The dataset a task's runs train and are evaluated on: the scene's, or the pose application's."""
    return f"results/{scene}/dataset.h5" if task == UPSAMPLING else f"results/{scene}/pose/dataset.h5"


def task_settings_file(scene: str, task: str) -> str:
    return f"results/{scene}/convs/{task}/settings.json"


def _operators(settings: Settings) -> dict[str, Any]:
    """One operators.h5 for every task: each convolution of the grid, as many levels as the deepest task asks."""
    levels = [settings["operators"]["levels"]]
    if POSE in tasks(settings):
        levels.append(application_settings(settings, POSE)["operators"]["levels"])
    return {"conv": conv_names(settings), "levels": max(levels)}


def operators_settings(settings: Settings) -> Settings:
    """settings.json of the grid's operators.h5: the scene's, with the grid's tables and levels."""
    return {**shared_settings(settings), "operators": _operators(settings)}


def task_settings(settings: Settings, task: str) -> Settings:
    """settings.json of a task's runs: the scene's (or the pose application's) with the grid's operators and, where
    `convs.epochs` is set, that many epochs; the architecture, convolution and seed are each run's flags."""
    own = shared_settings(settings) if task == UPSAMPLING else application_settings(settings, POSE)
    overlay: Settings = {"operators": _operators(settings)}
    if settings["convs"]["epochs"] is not None:
        overlay["training"] = {"epochs": settings["convs"]["epochs"]}
    return deep_merge(own, overlay)


def check(settings: Settings) -> None:
    """Every upsampling architecture of the grid resolves (templates in x, parseable) and no two are one network at
    a length once scaled to the width (the table would hold one run twice): one error line before any job."""
    archs, width = settings["convs"]["archs"], settings["network"]["width"]
    for conv in conv_names(settings):
        built: dict[str, str] = {}
        for entry, label in zip(archs, arch_labels(settings, UPSAMPLING)):
            network = str(_parsed(architecture(settings, UPSAMPLING, label, conv), "convs.archs").scaled(width))
            if network in built:
                raise PipelineError(f"workflow config: convs.archs: '{built[network]}' and '{entry}' are the same "
                                    f"network ({network}) at {conv}")
            built[network] = entry
