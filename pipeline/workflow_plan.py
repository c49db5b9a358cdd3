"""What a workflow config plans, checked and costed when the Snakefile loads, before Snakemake builds its DAG:
every scene resolved, its sequences listed and their motion-capture files found, each sequence's frames within
MAX_PLAYED_FRAMES, and each scene's jobs and simulated frames within MAX_SCENE_JOBS and MAX_SCENE_FRAMES unless
the config says `allow_large: true`. One line on stderr states the cost, and a second the largest scene's disk
once its mesh is made (`snakemake results/<scene>/subdiv.h5`, seconds: a frame's weight is its vertex counts); a problem is one `error:` line and exit
status 2 (pipeline.core.cli.exit_on_error), not Snakemake's stack of Snakefile frames.

The limits sit well above every shipped profile (the paper's garments: 65 sequences, ~20,000 frames a level,
~90 jobs) and the shared CMU library's paper run (312 windows, ~200,000 frames a level, ~340 jobs): `sequences:
2000` once planned 6,012 jobs without a word.
"""
from __future__ import annotations

import os
import re
import sys
from typing import Iterable

from pipeline.artifacts.subdiv import read_vertex_counts
from pipeline.core.config import resolve_scene
from pipeline.core.errors import PipelineError
from pipeline.workflow_paths import (HAND_MESH, check_bvh_files, check_targets, check_user_files, garment_files,
                                     is_hand, sequences_or_error, subdiv_file)
from scenes.bvh import MAX_PLAYED_FRAMES
from scenes.sequences import library_of, sequence_frames, sequence_names, sequence_shards

MAX_SCENE_JOBS = 1_000
MAX_SCENE_FRAMES = 500_000      # simulated a level
# What a frame weighs on disk: float32 positions (12 bytes a vertex) in a run, and in the dataset x_low, the target
# and at most this much besides (the mannequin's capsules and their velocities, its pose and body state: 3,800 bytes
# measured on the pants); the dataset keeps fewer frames than are simulated (the lead-ins).
POSITION_BYTES = 12
DATASET_FRAME_EXTRA = 4096
# The jobs of results/<scene>/ besides its sequences': settings, simulation settings, scene, subdivide,
# operators, dataset, train, evaluate and the target itself.
SCENE_JOBS = 9
SETTLE_JOBS = 3                 # a motion library's settle sequence: its scene and its two runs


def plan(config: dict, announce: bool = True, targets: Iterable[str] = ()) -> tuple[dict[str, dict], dict[str, list[str]]]:
    """Every scene's resolved settings and its sequence names, checked and costed (module docstring); with
    `announce`, the cost said in one line on stderr and the disk of each scene the targets name (no target: the
    default scene) in one line each (the Snakefile asks in its main process only: Snakemake parses it again in
    each process it spawns for a job, and the lines would repeat)."""
    settings = {scene: resolve_scene(config, scene) for scene in config["scenes"]}
    if config["default_scene"] not in settings:
        raise PipelineError(f"workflow config: default_scene '{config['default_scene']}' is not a scene "
                            f"(known: {', '.join(sorted(settings))})")
    sequences = {scene: sequences_or_error(scene, lambda: sequence_names(s)) for scene, s in settings.items()}
    check_targets(targets, settings)
    costs = {}
    for scene, names in sequences.items():
        check_bvh_files(scene, settings[scene], names)
        check_user_files(scene, settings[scene])
        costs[scene] = scene_cost(scene, settings[scene], names)
        if not config.get("allow_large", False):
            check_cost(scene, *costs[scene])
    if announce:
        print(_cost_line(costs), file=sys.stderr)
        for scene in targeted_scenes(targets, settings, config["default_scene"]):
            line = _hand_disk_line if is_hand(settings[scene]) else _disk_line
            print(line(scene, costs[scene]), file=sys.stderr)
    return settings, sequences


def scene_cost(scene: str, settings: dict, names: list[str]) -> tuple[int, int]:
    """(jobs, frames simulated a level) of results/<scene>/; an error for a sequence longer than
    MAX_PLAYED_FRAMES or a motion-capture header that cannot be read."""
    library = library_of(settings) is not None
    simulated = names + (["settle"] if library else [])
    frames = 0
    for name in simulated:
        try:
            length = sequence_frames(settings, name)
        except ValueError as err:
            raise PipelineError(f"scene '{scene}' sequence '{name}': {err}") from None
        if length > MAX_PLAYED_FRAMES:
            raise PipelineError(f"scene '{scene}' sequence '{name}': {length:,} frames, more than "
                                f"{MAX_PLAYED_FRAMES:,} (its settle, blend and hold frames and the clip it plays)")
        frames += length
    runs = len(sequence_shards(settings)) if settings["shard"] > 1 else len(names)
    dress = len(garment_files(settings))     # a garment from a file: its dress job
    return SCENE_JOBS + dress + len(names) + 2 * runs + SETTLE_JOBS * library, frames


def check_cost(scene: str, jobs: int, frames: int) -> None:
    """Refuse a scene beyond the limits, saying how to run it anyway."""
    if jobs > MAX_SCENE_JOBS or frames > MAX_SCENE_FRAMES:
        raise PipelineError(f"scene '{scene}' plans {jobs:,} jobs and {frames:,} frames a level, more than "
                            f"{MAX_SCENE_JOBS:,} jobs or {MAX_SCENE_FRAMES:,} frames: lower `sequences` (or the "
                            f"library's windows), or run with --config allow_large=true")


def targeted_scenes(targets: Iterable[str], scenes: Iterable[str], default_scene: str) -> list[str]:
    """The scenes whose `results/<scene>/...` the targets name, in order, once each; the default scene without
    targets."""
    named = [match[1] for target in targets if (match := re.match(r"results/([^/]+)", os.path.normpath(target)))]
    return list(dict.fromkeys(scene for scene in named if scene in scenes)) if targets else [default_scene]


def disk_bytes(n_low: int, n_high: int, frames: int) -> tuple[int, int]:
    """(bytes of the runs, at most bytes of the dataset) for `frames` simulated a level of a mesh of n_low -> n_high
    vertices."""
    positions = POSITION_BYTES * (n_low + n_high)
    return frames * positions, frames * (positions + DATASET_FRAME_EXTRA)


def _disk_line(scene: str, cost: tuple[int, int]) -> str:
    path = subdiv_file(scene)
    if not os.path.exists(path):
        return f"disk: known for {scene} once its mesh is made (`snakemake {path}`, seconds)"
    n_low, n_high = read_vertex_counts(path)
    runs, dataset = disk_bytes(n_low, n_high, cost[1])
    return (f"disk: {scene}, {n_low:,} -> {n_high:,} vertices: {_size(runs)} of runs "
            f"({_size(runs / cost[1])} a frame of both levels), at most {_size(dataset)} of dataset")


def _hand_disk_line(scene: str, cost: tuple[int, int]) -> str:
    """A hand scene's disk: its FEM runs store the skin a frame, its dataset the predictor and target besides."""
    path = f"results/{scene}/{HAND_MESH}"
    if not os.path.exists(path):
        return f"disk: known for {scene} once its mesh is made (`snakemake {path}`, seconds)"
    # Imported here, once a hand's mesh exists: the Snakefile imports this module at every start.
    from pipeline.artifacts.hand import read_skin_vertex_count
    runs, _ = disk_bytes(0, read_skin_vertex_count(path), cost[1])
    return (f"disk: {scene}, {read_skin_vertex_count(path):,} skin vertices: {_size(runs)} of FEM runs "
            f"({_size(runs / cost[1])} a frame), at most {_size(2 * runs + cost[1] * DATASET_FRAME_EXTRA)} of "
            f"dataset")


def _size(n_bytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n_bytes >= scale or unit == "kB":
            return f"{n_bytes / scale:,.1f} {unit}"


def _cost_line(costs: dict[str, tuple[int, int]]) -> str:
    largest = max(costs, key=lambda scene: costs[scene][::-1])
    jobs, frames = costs[largest]
    return (f"plan: {len(costs)} scene(s); the largest, {largest}: {jobs:,} jobs, {frames:,} frames simulated a "
            f"level (limits {MAX_SCENE_JOBS:,} and {MAX_SCENE_FRAMES:,} a scene)")
