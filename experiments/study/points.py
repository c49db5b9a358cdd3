"""The study's points as the workflow lays them out (workflow/rules/study.smk, `results/<scene>/study/`): from a
scene's name, its resolved settings and its sequence names, the points, the sequences of each count's dataset, the
training flags (step budget, frames) and width of its networks, and the `experiments.study` stage's arguments.
The Snakefile imports this at every start: it reads settings only and imports nothing heavy.
"""
from __future__ import annotations

from typing import Any

from pipeline.core.errors import PipelineError
from scenes.sequences import HELD_OUT, TRAIN, sequence_name, sequence_role

Settings = dict[str, Any]


def study_sequences(sequences: list[str], count: int) -> list[str]:
    """The first `count` training sequences (the scene's, and more made the same way where `count` exceeds its
    `sequences`) and every held-out one of the scene's `sequences`."""
    held_out = [name for name in sequences if sequence_role(name) == HELD_OUT]
    return [sequence_name(TRAIN, i) for i in range(count)] + held_out


def training_epochs(settings: Settings, count: int) -> int:
    """Epochs over `count` sequences that make as many optimiser steps as `study.epochs` (null: the scene's own
    training.epochs) over the scene's sequences; at least one."""
    epochs = settings["study"]["epochs"] or settings["training"]["epochs"]
    return max(1, round(epochs * settings["sequences"] / count))


def network_width(settings: Settings) -> float:
    """The study's networks' width: `study.width`, or the scene's network's where that is null."""
    return settings["study"]["width"] or settings["network"]["width"]


def point_labels(settings: Settings) -> list[str]:
    """The study's points, each a folder of results/<scene>/study/: `n<N>` (a dataset of the first N training
    sequences), `f<N>` (the scene's dataset within N training frames), `oracle` (the scene's dataset, the held-out
    motion trained on too)."""
    study = settings["study"]
    labels = ([f"n{n}" for n in study["sequence_counts"]] + [f"f{n}" for n in study["train_frames"]]
              + (["oracle"] if study["oracle"] else []))
    if not labels:
        raise PipelineError("workflow config: study: give sequence_counts, train_frames or oracle: true (no point "
                            "to train)")
    return labels


def own_dataset(label: str) -> bool:
    """Whether a point trains on a dataset of its own (`n<N>`) rather than the scene's."""
    return label.startswith("n")


def training_flags(settings: Settings, label: str) -> list[str]:
    """pipeline.train's flags that make a point what its label says: its step budget, and which frames."""
    study = settings["study"]
    epochs = study["epochs"] or settings["training"]["epochs"]
    if own_dataset(label):
        return ["--epochs", str(training_epochs(settings, int(label[1:])))]
    if label == "oracle":
        return ["--epochs", str(epochs), "--train-on", "train,held_out"]
    return ["--epochs", str(epochs), "--train-frames", label[1:]]     # the steps of every frame (pipeline.train)


def points(scene: str, settings: Settings) -> list[tuple[str, str, str]]:
    """(label, variant, eval.h5) of every point of the scene's study, by label then variant in config order."""
    return [(label, variant, f"results/{scene}/study/{label}/{variant}/eval.h5")
            for label in point_labels(settings) for variant in settings["study"]["variants"]]


def stage_arguments(scene: str, settings: Settings) -> list[str]:
    """`--point LABEL VARIANT EVAL.h5` for each point."""
    return [str(x) for point in points(scene, settings) for x in ("--point", *point)]
