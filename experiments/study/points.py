"""The study's points as the workflow lays them out (workflow/rules/study.smk, `results/<scene>/study/`): from a
scene's name, its resolved settings and its sequence names, the sequences of each count's dataset, the step budget
and width of its networks, and the `experiments.study` stage's arguments. The Snakefile imports this at every
start: it reads settings only and imports nothing heavy.
"""
from __future__ import annotations

from typing import Any

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


def points(scene: str, settings: Settings) -> list[tuple[int, str, str]]:
    """(count, variant, eval.h5) of every point of the scene's study, by count then variant in config order."""
    study = settings["study"]
    return [(n, variant, f"results/{scene}/study/n{n}/{variant}/eval.h5")
            for n in study["sequence_counts"] for variant in study["variants"]]


def stage_arguments(scene: str, settings: Settings) -> list[str]:
    """`--point COUNT VARIANT EVAL.h5` for each point."""
    return [str(x) for point in points(scene, settings) for x in ("--point", *point)]
