"""The multi-garment target as the workflow lays it out (workflow/rules/multi.smk, `results/multi/`): which scenes
are its garments, checked against the config's scenes and against each other, what the target stands for, and the
arguments of its training and report jobs. The Snakefile imports this at every start: it reads settings only and
imports nothing heavy (experiments.multi.stage checks the same agreement in the settings files, with torch).
"""
from __future__ import annotations

from typing import Any, Collection

from pipeline.core.errors import PipelineError

MULTI = "results/multi"
MULTI_PRODUCTS = ("model.pt", "train.h5", "multi.h5", "training_curve.png", "report.md")
GARMENT_PRODUCTS = ("model.pt", "eval.h5", "report.md", "report.html", "renders", "videos", "export")
# What one network's garments must share: its size and recipe, and the device it trains on.
SHARED_KEYS = ("network", "training", "device")


def check_garment_names(garments: list[str], scenes: Collection[str]) -> None:
    """The garments are scenes of the config, and no scene is named `multi` (the target's own folder)."""
    if "multi" in scenes:
        raise PipelineError("workflow config: a scene may not be named 'multi' (results/multi/ is the multi-garment "
                            "target)")
    unknown = [s for s in garments if s not in scenes]
    if unknown:
        raise PipelineError(f"workflow config: multi.scenes: '{unknown[0]}' is not a scene (known: "
                            f"{', '.join(sorted(scenes))})")


def check_shared_settings(garments: list[str], settings: dict[str, dict[str, Any]]) -> None:
    """Each garment's `SHARED_KEYS` settings are the first garment's; `settings` holds each scene's."""
    first = garments[0]
    for scene in garments[1:]:
        for key in SHARED_KEYS:
            if settings[scene][key] != settings[first][key]:
                raise PipelineError(f"results/multi/: scenes '{first}' and '{scene}' differ in {key}: the garments "
                                    f"of one network must share network.*, training.* and device")


def multi_products(garments: list[str]) -> list[str]:
    """What `results/multi/` stands for: the shared network, its table and report, and each garment's view of it
    with its evaluation."""
    return ([f"{MULTI}/{name}" for name in MULTI_PRODUCTS]
            + [f"{MULTI}/{scene}/{name}" for scene in garments for name in GARMENT_PRODUCTS])


def scene_files(garments: list[str], name: str) -> list[str]:
    """Each garment's scene's artifact `name` (results/<scene>/<name>)."""
    return [f"results/{scene}/{name}" for scene in garments]


def train_arguments(garments: list[str]) -> list[str]:
    """`--garment NAME SETTINGS.json DATASET.h5 OPERATORS.h5 VIEW.pt` for each garment."""
    return [x for scene in garments
            for x in ("--garment", scene, f"results/{scene}/settings.json", f"results/{scene}/dataset.h5",
                      f"results/{scene}/operators.h5", f"{MULTI}/{scene}/model.pt")]


def report_arguments(garments: list[str]) -> list[str]:
    """`--garment NAME SHARED_EVAL.h5 OWN_EVAL.h5` for each garment."""
    return [x for scene in garments
            for x in ("--garment", scene, f"{MULTI}/{scene}/eval.h5", f"results/{scene}/eval.h5")]
