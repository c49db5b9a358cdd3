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
window of a motion-capture file retargeted onto the mannequin (scenes.garment_scene.load_clip).

A garment scene with a motion library (`drivers.mannequin.library`) also has one sequence per window of each of
its files (scenes.library), after the programs: train_<file>_w<k> for a training subject, held_out_<file>_w<k>
for a held-out one (`library_windows.held_out_subjects`), each named after its file so that adding files leaves
the others' sequences as they were. Each window starts from the cloth settled once at rest (SETTLE). This module reads settings (and a library's file headers); the workflow and
pipeline.core.config use it, so it imports nothing heavy.
"""
from __future__ import annotations

import os
import re

from scenes.bvh import played_frames, read_bvh_header
from scenes.library import WINDOW_NAME, LibraryWindow, find_window, library_clips, subject_id, windows

TRAIN, HELD_OUT = "train", "held_out"
# A garment scene with a motion library also has its settle sequence (results/<scene>/settle/): the cloth settling
# on the body at rest for `settle_frames`, simulated once at each level; every window starts from its last frame.
SETTLE = "settle"
# A sequence's name: its role, then its index among that role's programs or held-out clips, or a library window's
# file and index (no braces: Snakemake reads them as wildcards).
INDEXED_NAME = r"(?:train|held_out)_[0-9][0-9][0-9]+"
NAME_PATTERN = rf"(?:train|held_out)_(?:[0-9][0-9][0-9]+|{WINDOW_NAME})"


def sequence_name(role: str, index: int) -> str:
    return f"{role}_{index:03d}"


def window_sequence_name(role: str, window: LibraryWindow) -> str:
    return f"{role}_{window.key}"


def sequence_role(name: str) -> str:
    """train or held_out: the role a sequence name starts with (the settle sequence's: settle)."""
    if name == SETTLE:
        return SETTLE
    if not re.fullmatch(NAME_PATTERN, name):
        raise ValueError(f"'{name}' is not a sequence name (train_000, ..., held_out_000, ..., or a library "
                         f"window's such as train_001-01-01_w00)")
    return HELD_OUT if name.startswith(HELD_OUT) else TRAIN


def is_window_name(name: str) -> bool:
    """Whether sequence `name` is a library window's."""
    return not re.fullmatch(INDEXED_NAME, name) and re.fullmatch(NAME_PATTERN, name) is not None


def parse_sequence_name(name: str) -> tuple[str, int]:
    """(role, index) of a program's or held-out clip's sequence name such as 'train_003'."""
    if not re.fullmatch(INDEXED_NAME, name):
        raise ValueError(f"'{name}' is not a sequence name (train_000, train_001, ..., held_out_000, ...)")
    role, index = name.rsplit("_", 1)
    return role, int(index)


def window_key(name: str) -> str:
    """A library window sequence's name less its role: what scenes.library.find_window looks up."""
    return name.removeprefix(f"{sequence_role(name)}_")


def clip_key(entry: str | dict) -> str:
    """What identifies a clip entry: its kind, or its BVH file (normalised path) and window."""
    if isinstance(entry, str):
        return entry
    return f"bvh:{os.path.normpath(entry['bvh'])}@{entry.get('start', '')}-{entry.get('end', '')}"


# The generators of scenes whose cloth the mannequin wears: the procedural garments and a garment from a file.
GARMENT_GENERATORS = ("garment", "garment_file")


def wears_garment(settings: dict) -> bool:
    """Whether the scene's cloth is a garment on the mannequin (it has clips, capsules, attachment pins)."""
    return settings["mesh"]["generator"] in GARMENT_GENERATORS


# The generators of the FEM hand scenes: the procedural hand and a user's hand from a mesh and a bone file.
HAND_GENERATORS = ("hand", "hand_file")


def is_hand(settings: dict) -> bool:
    """Whether a scene is a hand moved by the FEM (its joint angles, FEM runs and dataset) rather than cloth."""
    return settings["mesh"]["generator"] in HAND_GENERATORS


def held_out_clips(settings: dict) -> list:
    """The held-out clip entries when `dataset.split` is `held_out`: a garment's `drivers.mannequin.test_clips`, the
    hand's `drivers.hand.test_motions`; else none."""
    if settings["dataset"]["split"] != HELD_OUT:
        return []
    if wears_garment(settings):
        return list(settings["drivers"]["mannequin"]["test_clips"])
    if is_hand(settings):
        return list(settings["drivers"]["hand"]["test_motions"])
    return []


def training_clips(settings: dict) -> list:
    """The clip entries training sequences draw from: the mannequin's clips less the held-out ones."""
    held = {clip_key(entry) for entry in held_out_clips(settings)}
    return [entry for entry in settings["drivers"]["mannequin"]["clips"] if clip_key(entry) not in held]


def library_of(settings: dict) -> dict | None:
    """The scene's motion library settings (`drivers.mannequin.library`), or None."""
    if not wears_garment(settings):
        return None
    return settings["drivers"]["mannequin"].get("library")


def library_windows(settings: dict) -> dict[str, list[LibraryWindow]]:
    """The windows of the scene's motion library by role, in file order (none without a library); settings as
    resolved, with `library_windows`. A subject of `held_out_subjects` is held out when `dataset.split` is
    held_out (pipeline.core.config refuses it otherwise)."""
    library = library_of(settings)
    found = {TRAIN: [], HELD_OUT: []}
    if library is None:
        return found
    selection = settings["library_windows"]
    held = {subject_id(s) for s in selection["held_out_subjects"]}
    for clip in library_clips(library, selection):
        found[HELD_OUT if clip.subject in held else TRAIN] += windows(clip, library["window"])
    return found


def sequence_names(settings: dict) -> list[str]:
    """Every sequence of a scene, training ones first (the programs, then the library's windows), then the
    held-out ones (the test clips, then the held-out subjects' windows); `settings` as resolved, with the
    `sequences` count and `library_windows`."""
    by_role = library_windows(settings)
    return ([sequence_name(TRAIN, i) for i in range(settings["sequences"])]
            + [window_sequence_name(TRAIN, w) for w in by_role[TRAIN]]
            + [sequence_name(HELD_OUT, i) for i in range(len(held_out_clips(settings)))]
            + [window_sequence_name(HELD_OUT, w) for w in by_role[HELD_OUT]])


def sequence_shards(settings: dict) -> list[list[str]]:
    """The scene's sequences in groups of `shard` (settings as resolved), each a batch one simulate job steps
    together: training and held-out sequences apart, the programs and test clips in order, then the library's
    windows by length (then name). A batch steps its longest sequence's frames, so windows of like length together
    step fewer batch frames: 3,779 instead of 4,267 for the shared CMU library in 64-window shards (planned from
    its headers, 2026-11-26), 11 % of the GPU's stepping. Raising `sequences` or adding files regroups the shards
    after the first one that changes, as it did in name order; the dataset takes the sequences in sequence_names'
    order whatever the batches."""
    size = settings["shard"]
    by_role = library_windows(settings)
    indexed = {TRAIN: [sequence_name(TRAIN, i) for i in range(settings["sequences"])],
               HELD_OUT: [sequence_name(HELD_OUT, i) for i in range(len(held_out_clips(settings)))]}
    shards = []
    for role in (TRAIN, HELD_OUT):
        # Rounded: the windows of one file are equally long up to the last bits of their float ends.
        by_length = sorted(by_role[role], key=lambda w: (round(w.end - w.start, 6), w.key))
        names = indexed[role] + [window_sequence_name(role, w) for w in by_length]
        shards += [names[i:i + size] for i in range(0, len(names), size)]
    return shards


def sequence_clips(settings: dict, name: str) -> list:
    """The clip entries sequence `name` plays (a training program: the pool it draws from), for a program or a
    held-out clip's sequence (a library window's: scenes.library.find_window)."""
    role, index = parse_sequence_name(name)
    if role == TRAIN:
        return training_clips(settings)
    held = held_out_clips(settings)
    if index >= len(held):
        raise ValueError(f"no sequence '{name}': the scene holds out {len(held)} clip(s)")
    return [held[index]]


def sequence_bvh_files(settings: dict, name: str) -> list[str]:
    """The motion-capture files sequence `name` reads (none for a grid scene)."""
    if not wears_garment(settings):
        return []
    if is_window_name(name):
        return [find_window(library_of(settings), window_key(name)).clip.path]
    return [entry["bvh"] for entry in sequence_clips(settings, name) if isinstance(entry, dict)]


def sequence_frames(settings: dict, name: str) -> int:
    """The frames sequence `name` (or SETTLE) simulates, planned from the settings and motion-capture headers
    alone: a program's or a grid's `frames`; a held-out BVH clip's settle_frames and the frames it plays (its
    whole length as the header states it, or its start-end window); a library window's blend and hold frames and
    its seconds of motion; the settle sequence's settle_frames and its frame 0. ValueError for an unreadable
    header."""
    fps = 1.0 / settings["solver"]["dt"]
    drive = settings["drivers"].get("mannequin")
    if name == SETTLE:
        return drive["settle_frames"] + 1
    if is_window_name(name):
        window = find_window(library_of(settings), window_key(name))
        return (drive["blend_frames"] + drive["library"]["hold_frames"]
                + played_frames(window.end - window.start, fps))
    role, index = parse_sequence_name(name)
    entry = held_out_clips(settings)[index] if role == HELD_OUT else None
    if not isinstance(entry, dict):
        return settings["frames"]
    return drive["settle_frames"] + played_frames(_clip_seconds(entry), fps)


def _clip_seconds(entry: dict) -> float:
    """Seconds a BVH clip entry plays at most: its window, or the file's whole length from its header (the
    retargeter may drop a leading rest pose)."""
    header = read_bvh_header(entry["bvh"])
    end = entry.get("end", (header.n_frames - 1) * header.frame_time)
    return end - entry.get("start", 0.0)
