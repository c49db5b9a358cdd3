"""A motion-capture library as a scene's sequences: every BVH file under a folder (`.bvh` or `.bvh.gz`) cut into
windows of `window` seconds, each window one sequence (the paper trained on the CMU database this way).

What a window plays is set by the scene's `drivers.mannequin.library` (in settings.json): the folder, a manifest
(tab-separated, a `file` column of paths relative to the folder, and optionally `subject`, `category`,
`description` and a column of true frame rates), per-file frame-rate overrides (headers of real libraries
sometimes claim 120 fps for trials captured at 60), the window length and the hold in the clip's first pose. Which
windows exist is the workflow's business (`library_windows`, like `sequences`, kept out of settings.json, so
that choosing more clips or other held-out subjects remakes none of the sequences already made): include and
exclude globs, at most `max_clips` files (0: all), and whole subjects held out. The folder is listed and each
file's header read once per process.

A window's sequence is named after its file and index (`train_001-01-01_w02`: file 001/01_01.bvh.gz, window 2, a
training subject), so adding files to the folder adds sequences and leaves the others as they were. Planning reads
each file's header only (scenes.bvh.read_bvh_header); a file whose header cannot be
read still gets one window, and the scene stage drops that sequence with the reason, as it drops a clip it cannot
map onto the mannequin: one bad file never stops a run.
"""
from __future__ import annotations

import csv
import dataclasses
import functools
import math
import os
import re
from fnmatch import fnmatch
from pathlib import Path

from scenes.bvh import read_bvh_header
from scenes.retarget import REST_LEAD_FRAMES

BVH_SUFFIXES = (".bvh", ".bvh.gz")
# After the role: a file's slug and the window's index (no braces: Snakemake reads them as wildcards).
WINDOW_NAME = r"[A-Za-z0-9-]+_w[0-9][0-9]+"


@dataclasses.dataclass(frozen=True)
class LibraryClip:
    """One file of a library, as planning sees it."""
    file: str               # path relative to the library folder, '/'-separated
    path: str               # as opened: the folder joined with `file`
    slug: str               # `file` as a sequence name allows: letters, digits and '-'
    subject: str            # the manifest's subject, else the file's first folder, else its slug
    category: str           # the manifest's category ("" without one)
    description: str        # the manifest's description ("" without one)
    frame_time: float | None    # seconds per frame as the clip plays it; None where the header is unreadable
    n_frames: int               # frames in the file (1 where the header is unreadable)
    problem: str = ""       # why planning could not read it ("" when it could)

    @property
    def motion_seconds(self) -> float:
        """Seconds of motion as planned from the header alone, which cannot tell whether the file starts with a
        T-pose and a converter's blend out of it: as if it did (the retargeter drops those REST_LEAD_FRAMES,
        scenes.retarget.motion_start), so that no window reaches past the motion."""
        return 0.0 if self.frame_time is None else max(self.n_frames - 1 - REST_LEAD_FRAMES, 0) * self.frame_time


class UnusableWindow(ValueError):
    """A window that cannot be played: its file cannot be read or mapped onto the mannequin, or its retargeted
    pose drives limbs through each other. The scene stage drops its sequence, with this as the reason, and the
    run goes on."""


@dataclasses.dataclass(frozen=True)
class LibraryWindow:
    """A window of a clip: seconds [start, end) of its motion, one sequence."""
    clip: LibraryClip
    index: int
    start: float
    end: float

    @property
    def key(self) -> str:
        """The sequence name without its role: the file's slug and the window's index."""
        return f"{self.clip.slug}_w{self.index:02d}"

    def describe(self) -> dict:
        """What a report says of the window (scene.h5 attr `library_window`)."""
        clip = self.clip
        return {"file": clip.file, "subject": clip.subject, "category": clip.category,
                "description": clip.description, "start": self.start, "end": self.end,
                "frame_time": clip.frame_time}


def slug(file: str) -> str:
    """A library path as a sequence name part: without its BVH suffix, every run of other characters than letters
    and digits one '-' (001/01_01.bvh.gz -> 001-01-01)."""
    stem = next((file[:-len(s)] for s in BVH_SUFFIXES if file.lower().endswith(s)), file)
    return re.sub(r"[^A-Za-z0-9]+", "-", stem).strip("-") or "clip"


def library_clips(library: dict, selection: dict | None = None) -> list[LibraryClip]:
    """Every clip of the library folder that `selection` (`library_windows`: include, exclude, max_clips) keeps,
    sorted by file, each planned from its header; without a selection, every BVH file (what the scene stage
    searches to find a sequence's file). An error for a folder or a manifest that does not exist or cannot be
    read: a library that is not there is the config's mistake, not one bad clip's."""
    clips = _all_clips(*_frozen(library))
    if selection is None:
        return list(clips)
    kept = [c for c in clips if any(fnmatch(c.file, g) for g in selection["include"])
            and not any(fnmatch(c.file, g) for g in selection["exclude"])]
    return kept[:selection["max_clips"]] if selection["max_clips"] else kept


def _frozen(library: dict) -> tuple:
    """What a library's clips depend on, hashable (the folder's listing is read once per process)."""
    return (library["dir"], library["manifest"], library["fps_column"], tuple(sorted(library["frame_rates"].items())))


@functools.lru_cache(maxsize=None)
def _all_clips(folder_name: str, manifest_name: str | None, fps_column: str | None,
               frame_rates: tuple[tuple[str, float], ...]) -> tuple[LibraryClip, ...]:
    folder = Path(folder_name)
    if not folder.is_dir():
        raise ValueError(f"{folder}: motion library folder does not exist (relative paths start in {Path.cwd()})")
    manifest = _manifest(folder, manifest_name)
    files = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                   if p.is_file() and p.name.lower().endswith(BVH_SUFFIXES))
    rates = {"fps_column": fps_column, "frame_rates": dict(frame_rates)}
    return tuple(_clip(folder, file, manifest.get(file, {}), rates) for file in files)


def windows(clip: LibraryClip, window: float) -> list[LibraryWindow]:
    """The windows of a clip: its motion cut into the fewest equal windows of at most `window` seconds, so that
    none of it is left out (whole windows of `window` seconds would leave out 20,000 of the shared CMU library's
    129,000 frames at 10 s) and a batch of windows steps sequences of similar lengths (between half a window and
    one)."""
    n = max(1, math.ceil(clip.motion_seconds / window - 1e-9))
    length = clip.motion_seconds / n
    return [LibraryWindow(clip, k, k * length, (k + 1) * length) for k in range(n)]


def subject_id(text: str) -> str:
    """A subject as compared: a number without its leading zeros ('016' and '16' are one subject), else as given."""
    text = text.strip()
    return str(int(text)) if text.isdigit() else text


def find_window(library: dict, key: str) -> LibraryWindow:
    """The window a sequence name's `key` (LibraryWindow.key) names; ValueError if the folder has no such file
    or the file no such window."""
    file_slug, index = key.rsplit("_w", 1)
    clips = [clip for clip in library_clips(library) if clip.slug == file_slug]
    if not clips:
        raise ValueError(f"{library['dir']}: no BVH file whose name gives '{file_slug}'")
    if len(clips) > 1:
        raise ValueError(f"{library['dir']}: files {', '.join(c.file for c in clips)} give one sequence name "
                         f"'{file_slug}': rename one")
    found = windows(clips[0], library["window"])
    if int(index) >= len(found):
        raise ValueError(f"{clips[0].path}: has {len(found)} window(s) of {library['window']:g} s, not "
                         f"{int(index) + 1}")
    return found[int(index)]


def _clip(folder: Path, file: str, row: dict[str, str], rates: dict) -> LibraryClip:
    path = os.path.join(str(folder), file)
    parts = file.split("/")
    subject = subject_id(row.get("subject") or (parts[0] if len(parts) > 1 else slug(file)))
    meta = dict(file=file, path=path, slug=slug(file), subject=subject, category=row.get("category", ""),
                description=row.get("description", ""))
    try:
        header = read_bvh_header(path)
    except ValueError as err:
        return LibraryClip(**meta, frame_time=None, n_frames=1, problem=str(err))
    return LibraryClip(**meta, frame_time=_frame_time(file, row, rates, header.frame_time),
                       n_frames=header.n_frames)


def _frame_time(file: str, row: dict[str, str], rates: dict, header_frame_time: float) -> float:
    """Seconds per frame: a `frame_rates` glob of the config, else the manifest's frame-rate column
    (`fps_column`), else the header's."""
    for pattern, fps in rates["frame_rates"].items():
        if fnmatch(file, pattern):
            return 1.0 / fps
    column = rates["fps_column"]
    if column and row.get(column):
        try:
            fps = float(row[column])
        except ValueError:
            fps = math.nan
        if math.isfinite(fps) and fps > 0:
            return 1.0 / fps
    return header_frame_time


def _manifest(folder: Path, name: str | None) -> dict[str, dict[str, str]]:
    """The manifest's rows by file (empty without one)."""
    if name is None:
        return {}
    path = folder / name
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f, delimiter="\t"))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise ValueError(f"{path}: cannot read the library's manifest ({err})") from None
    if rows and "file" not in rows[0]:
        raise ValueError(f"{path}: the manifest has no 'file' column (tab-separated, a header row first)")
    return {row["file"]: row for row in rows if row.get("file")}
