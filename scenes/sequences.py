"""The sequences of a scene: their names and roles, and the clips a garment scene's sequence plays.

A scene's frames come in sequences, each a unit of work (its own scene file and simulations). A garment scene has
`sequences` training sequences, train_000, train_001, ..., each a seeded motion program (scenes.program) over
the training clips, and, when `dataset.split` is `held_out`, one held-out sequence per test clip, held_out_000,
..., which plays that clip alone after the settle period (scenes.motion.play_clips). The training clips are
`drivers.mannequin.clips` less the test clips, so a held-out clip never plays in a training sequence. A grid
scene has one sequence, train_000. A sequence is made from the scene's settings and its own name alone: adding
sequences leaves the others as they were.

A clip entry of the settings is a procedural kind (scenes.motion.MOTION_KINDS) or a mapping
{bvh: PATH, start: SECONDS, end: SECONDS} (start and end optional; PATH relative to the working directory), a
window of a motion-capture file retargeted onto the mannequin (scenes.garment_scene.load_clip). This module reads
settings only (the workflow and pipeline.core.config use it), so it imports nothing heavy.
"""
from __future__ import annotations

import os
import re

TRAIN, HELD_OUT = "train", "held_out"
# A sequence's name: its role and its index among that role's (no braces: Snakemake reads them as wildcards).
NAME_PATTERN = r"(?:train|held_out)_[0-9][0-9][0-9]+"


def sequence_name(role: str, index: int) -> str:
    return f"{role}_{index:03d}"


def parse_sequence_name(name: str) -> tuple[str, int]:
    """(role, index) of a sequence name such as 'train_003'."""
    if not re.fullmatch(NAME_PATTERN, name):
        raise ValueError(f"'{name}' is not a sequence name (train_000, train_001, ..., held_out_000, ...)")
    role, index = name.rsplit("_", 1)
    return role, int(index)


def clip_key(entry: str | dict) -> str:
    """What identifies a clip entry: its kind, or its BVH file (normalised path) and window."""
    if isinstance(entry, str):
        return entry
    return f"bvh:{os.path.normpath(entry['bvh'])}@{entry.get('start', '')}-{entry.get('end', '')}"


def held_out_clips(settings: dict) -> list:
    """The held-out clip entries: `drivers.mannequin.test_clips` when `dataset.split` is `held_out`, else none."""
    if settings["mesh"]["generator"] != "garment" or settings["dataset"]["split"] != HELD_OUT:
        return []
    return list(settings["drivers"]["mannequin"]["test_clips"])


def training_clips(settings: dict) -> list:
    """The clip entries training sequences draw from: the mannequin's clips less the held-out ones."""
    held = {clip_key(entry) for entry in held_out_clips(settings)}
    return [entry for entry in settings["drivers"]["mannequin"]["clips"] if clip_key(entry) not in held]


def sequence_names(settings: dict) -> list[str]:
    """Every sequence of a scene, training ones first; `settings` as resolved, with the `sequences` count."""
    return ([sequence_name(TRAIN, i) for i in range(settings["sequences"])]
            + [sequence_name(HELD_OUT, i) for i in range(len(held_out_clips(settings)))])


def sequence_shards(settings: dict) -> list[list[str]]:
    """The scene's sequences in groups of `shard` (settings as resolved), each a batch one simulate job steps
    together: training and held-out sequences apart and in order, so raising `sequences` changes only the last
    training shard."""
    size = settings["shard"]
    names = sequence_names(settings)
    shards = []
    for role in (TRAIN, HELD_OUT):
        of_role = [name for name in names if parse_sequence_name(name)[0] == role]
        shards += [of_role[i:i + size] for i in range(0, len(of_role), size)]
    return shards


def sequence_clips(settings: dict, name: str) -> list:
    """The clip entries sequence `name` plays (a training sequence: the pool its program draws from)."""
    role, index = parse_sequence_name(name)
    if role == TRAIN:
        return training_clips(settings)
    held = held_out_clips(settings)
    if index >= len(held):
        raise ValueError(f"no sequence '{name}': the scene holds out {len(held)} clip(s)")
    return [held[index]]


def sequence_bvh_files(settings: dict, name: str) -> list[str]:
    """The motion-capture files sequence `name` reads (none for a grid scene)."""
    if settings["mesh"]["generator"] != "garment":
        return []
    return [entry["bvh"] for entry in sequence_clips(settings, name) if isinstance(entry, dict)]
