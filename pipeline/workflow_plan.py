"""What a workflow config plans, checked and costed when the Snakefile loads, before Snakemake builds its DAG:
every scene resolved, its sequences listed and their motion-capture files found, each sequence's frames within
MAX_PLAYED_FRAMES, and each scene's jobs and simulated frames within MAX_SCENE_JOBS and MAX_SCENE_FRAMES unless
the config says `allow_large: true`. One line on stderr states the cost; a problem is one `error:` line and exit
status 2 (pipeline.core.cli.exit_on_error), not Snakemake's stack of Snakefile frames.

The limits sit well above every shipped profile (the paper's garments: 65 sequences, ~20,000 frames a level,
~90 jobs) and the shared CMU library's paper run (312 windows, ~200,000 frames a level, ~340 jobs): `sequences:
2000` once planned 6,012 jobs without a word.
"""
from __future__ import annotations

import sys

from pipeline.core.config import resolve_scene
from pipeline.core.errors import PipelineError
from pipeline.workflow_paths import check_bvh_files, check_garment_file, garment_files, sequences_or_error
from scenes.bvh import MAX_PLAYED_FRAMES
from scenes.sequences import library_of, sequence_frames, sequence_names, sequence_shards

MAX_SCENE_JOBS = 1_000
MAX_SCENE_FRAMES = 500_000      # simulated a level
# The jobs of results/<scene>/ besides its sequences': settings, simulation settings, scene, subdivide,
# operators, dataset, train, evaluate and the target itself.
SCENE_JOBS = 9
SETTLE_JOBS = 3                 # a motion library's settle sequence: its scene and its two runs


def plan(config: dict) -> tuple[dict[str, dict], dict[str, list[str]]]:
    """Every scene's resolved settings and its sequence names, checked and costed (module docstring); the cost
    said in one line on stderr."""
    settings = {scene: resolve_scene(config, scene) for scene in config["scenes"]}
    if config["default_scene"] not in settings:
        raise PipelineError(f"workflow config: default_scene '{config['default_scene']}' is not a scene "
                            f"(known: {', '.join(sorted(settings))})")
    sequences = {scene: sequences_or_error(scene, lambda: sequence_names(s)) for scene, s in settings.items()}
    costs = {}
    for scene, names in sequences.items():
        check_bvh_files(scene, settings[scene], names)
        check_garment_file(scene, settings[scene])
        costs[scene] = scene_cost(scene, settings[scene], names)
        if not config.get("allow_large", False):
            check_cost(scene, *costs[scene])
    print(_cost_line(costs), file=sys.stderr)
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


def _cost_line(costs: dict[str, tuple[int, int]]) -> str:
    largest = max(costs, key=lambda scene: costs[scene][::-1])
    jobs, frames = costs[largest]
    return (f"plan: {len(costs)} scene(s); the largest, {largest}: {jobs:,} jobs, {frames:,} frames simulated a "
            f"level (limits {MAX_SCENE_JOBS:,} and {MAX_SCENE_FRAMES:,} a scene)")
