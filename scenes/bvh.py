"""Reading Biovision BVH motion capture: the joint tree, its rest offsets and the per-frame local transforms.

A small parser rather than a library: the format is a dozen keywords, and the one well-known reader (bvhio) adds
two dependencies (PyGLM, spatial-transform), works joint by joint in Python objects and raises its own errors,
where we want arrays and a one-line ValueError naming the line. Euler angles go through scipy's Rotation.

Files are read as UTF-8 text (a byte-order mark allowed), gunzipped where the name ends in `.gz`, as motion libraries
are kept; read_bvh_header reads a file only as far as its MOTION header (a library reads every file's header at
every start), with the same parser as the full read.

A file from elsewhere is read within bounds, checked as it streams in, so that no file makes the reader run out of
memory, time or stack: lines of at most MAX_LINE characters and MAX_TEXT in all (a file of zeros without a newline
was once read whole as one line), MAX_JOINTS joints parsed without recursion (10,000 nested joints overflowed the
stack), at most six channels a joint, finite numbers, and no more than MAX_CLIP_VALUES numbers in the arrays a
clip fills (frames x (channels + 7 per joint)), checked before they are allocated. An error names the file, the
line and the problem, never the file's words: a path mistyped as /proc/self/environ once put the environment into
the logs.

Conventions (those of the BVH format as Blender and MotionBuilder read it): a joint's CHANNELS list its Euler
rotations in the order they compose, R = R_first R_second R_third, in degrees; its local translation is its OFFSET,
or its position channels where it has them; the rest pose has every rotation the identity. Quaternions are
(x, y, z, w) like the mannequin's (scenes.kinematics). Lengths are converted to metres on reading (see UNITS);
axes are kept as in the file (Y-up or Z-up): the retargeting works them out from the skeleton itself.
"""
from __future__ import annotations

import gzip
import itertools
import math
import numbers
import zlib
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np
from scipy.spatial.transform import Rotation

# Metres per file unit. CMU's ASF-derived files use 1/0.45 inch; the others are the usual ones.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "CMU ASF unit": 0.0254 / 0.45}
TYPICAL_EXTENT = 1.7  # metres: a standing adult's rest pose spans about this much (height or arm span)

# Bounds far beyond real capture (CMU's rigs have 31-100 joints, its longest clips 3,262 frames, 1.3 MB): a
# file of CMU's 31-joint rig at 120 fps may still run 44 minutes.
MAX_JOINTS = 1000
MAX_CLIP_VALUES = 100_000_000      # float64s a clip fills: 800 MB
MAX_LINE = 1 << 20                 # characters; a frame of 1000 joints x 6 channels takes about 60,000
MAX_TEXT = 1 << 30                 # characters in all
# Frames a clip plays on the mannequin, resampled at the scene's rate: the bound of a sequence's `frames` in
# workflow/config.schema.yaml, which a clip's length (its frame time, its window, the scene's dt) would bypass.
MAX_PLAYED_FRAMES = 100_000


@dataclass(frozen=True, eq=False)
class BvhClip:
    """A BVH file's skeleton and motion, lengths in metres. Joints are in file order (parents first)."""
    name: str                         # the file's name without .bvh(.gz), for messages and clip names
    names: tuple[str, ...]            # (J,) joint names
    parents: np.ndarray               # (J,) int64, -1 for the root
    offsets: np.ndarray               # (J, 3) rest position of each joint in its parent's frame
    end_sites: dict[int, np.ndarray]  # joint index -> its End Site's offset (3,) in the joint's frame
    frame_time: float                 # seconds
    positions: np.ndarray             # (F, J, 3) local translation of each joint per frame
    rotations: np.ndarray             # (F, J, 4) local rotation of each joint per frame
    unit_scale: float                 # metres per file unit

    @property
    def n_frames(self) -> int:
        return len(self.positions)

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.n_frames - 1) * self.frame_time

    def rest_positions(self) -> np.ndarray:
        """World positions (J, 3) of the joints in the rest pose."""
        return _chain_sums(self.parents, self.offsets)


@dataclass(frozen=True)
class BvhHeader:
    """What a BVH file says before its motion data."""
    names: tuple[str, ...]  # joint names in file order (parents first)
    n_frames: int
    frame_time: float       # seconds, as the file states it


def read_bvh(path: str | Path, scale: float | None = None, frame_time: float | None = None) -> BvhClip:
    """Read a BVH file (`.bvh`, or gzip-compressed `.bvh.gz`). `scale` is metres per file unit; by default it is
    the unit of UNITS whose rest-pose extent comes closest to TYPICAL_EXTENT (inches, CMU's 1/0.45 inch, cm, mm
    and m are far apart). `frame_time` (seconds) replaces the header's where that is wrong (some libraries claim
    120 fps for trials captured at 60). Errors are one-line ValueErrors that start with the path."""
    path = Path(path)
    with _lines(path) as lines:
        return _parse(_Tokens(lines, str(path)), _clip_name(path), scale, frame_time)


def played_frames(seconds: float, fps: float) -> int:
    """Frames `seconds` of a clip's motion play at `fps`, both ends included (scenes.retarget resamples so)."""
    return int(math.floor(seconds * fps + 1e-6)) + 1   # 1e-6: rounded frame times


def read_bvh_header(path: str | Path) -> BvhHeader:
    """The joint names, frame count and frame time of a BVH file (`.bvh` or `.bvh.gz`), read only as far as the
    'Frame Time:' line: the hierarchy is checked as read_bvh checks it, the motion data is not read."""
    path = Path(path)
    with _lines(path) as lines:
        tree, n_frames, frame_time = _parse_header(_Tokens(lines, str(path)))
    return BvhHeader(names=tuple(tree.names), n_frames=n_frames, frame_time=frame_time)


def parse_bvh(text: str, name: str = "clip", source: str = "<bvh>", scale: float | None = None,
              frame_time: float | None = None) -> BvhClip:
    """Parse BVH text; errors are one-line ValueErrors that start with `source` and the line number."""
    return _parse(_Tokens(text.splitlines(), source), name, scale, frame_time)


def _parse(tokens: _Tokens, name: str, scale: float | None, frame_time: float | None) -> BvhClip:
    """The whole file: its header, then the motion data (frame_time, where given, replaces the header's)."""
    source = tokens.source
    if frame_time is not None and not (isinstance(frame_time, numbers.Real) and not isinstance(frame_time, bool)
                                       and math.isfinite(frame_time) and frame_time > 0):
        raise ValueError(f"{source}: the frame time given must be a positive finite number of seconds, "
                         f"got {frame_time!r}")
    tree, n_frames, header_frame_time = _parse_header(tokens)
    frame_time = header_frame_time if frame_time is None else frame_time
    values = tokens.frames(n_frames, sum(len(c) for c in tree.channels))
    offsets = np.array(tree.offsets)
    if scale is None:
        scale = _detect_unit_scale(tree, offsets, source)
    elif not scale > 0:
        raise ValueError(f"{source}: scale must be positive, got {scale}")
    positions = np.broadcast_to(offsets, (n_frames,) + offsets.shape).copy()
    rotations = np.tile([0.0, 0.0, 0.0, 1.0], (n_frames, len(offsets), 1))
    column = 0
    for joint, channels in enumerate(tree.channels):
        order = "".join(axis for axis, kind in channels if kind == "rotation")
        for k, (axis, kind) in enumerate(channels):
            if kind == "position":
                positions[:, joint, "XYZ".index(axis)] = values[:, column + k]
        if order:
            angles = values[:, [column + k for k, (_, kind) in enumerate(channels) if kind == "rotation"]]
            rotations[:, joint] = Rotation.from_euler(order, angles, degrees=True).as_quat()
        column += len(channels)
    return BvhClip(name=name, names=tuple(tree.names), parents=np.array(tree.parents, dtype=np.int64),
                   offsets=offsets * scale, end_sites={j: np.asarray(o) * scale for j, o in tree.end_sites.items()},
                   frame_time=float(frame_time), positions=positions * scale, rotations=rotations,
                   unit_scale=float(scale))


def _parse_header(tokens: _Tokens) -> tuple[_Tree, int, float]:
    """The hierarchy and the MOTION header up to the frame time (the last word read)."""
    tokens.expect("HIERARCHY")
    tokens.expect("ROOT")
    tree = _parse_hierarchy(tokens)
    tokens.expect("MOTION")
    tokens.expect("Frames:")
    n_frames = tokens.count("frame count", 1, MAX_CLIP_VALUES)
    held = n_frames * (sum(len(c) for c in tree.channels) + 7 * len(tree.names))
    if held > MAX_CLIP_VALUES:
        tokens.fail(f"{n_frames} frames of {len(tree.names)} joints would hold {held:,} numbers, more than "
                    f"{MAX_CLIP_VALUES:,} (a shorter file, or a window of it)")
    tokens.expect("Frame")
    tokens.expect("Time:")
    frame_time = tokens.number("frame time")
    if not frame_time > 0:
        tokens.fail(f"frame time must be positive, got {frame_time}")
    return tree, n_frames, frame_time


@contextmanager
def _lines(path: Path) -> Iterator[Iterable[str]]:
    """The file's lines, read as they are asked for and gunzipped where its name ends in .gz; a corrupt gzip
    stream or bytes that are not UTF-8 give one ValueError starting with the path."""
    opener = gzip.open if path.suffix.lower() == ".gz" else open
    try:
        with opener(path, "rt", encoding="utf-8-sig") as stream:
            yield _bounded_lines(stream, path)
    except (gzip.BadGzipFile, EOFError, zlib.error):
        # gzip's own message quotes the file's first bytes
        raise ValueError(f"{path}: not a readable gzip file (a damaged or cut-short stream)") from None
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not UTF-8 text ({err.reason})") from None


def _bounded_lines(stream, path: Path) -> Iterator[str]:
    """The stream's lines, each read no further than MAX_LINE characters, and no more than MAX_TEXT in all."""
    total = 0
    for number in itertools.count(1):
        line = stream.readline(MAX_LINE + 1)
        if not line:
            return
        total += len(line)
        if len(line) > MAX_LINE or total > MAX_TEXT:
            too_long = f"line longer than {MAX_LINE:,}" if len(line) > MAX_LINE else f"more than {MAX_TEXT:,}"
            raise ValueError(f"{path}:{number}: {too_long} characters: not a BVH file this reader takes")
        yield line


def _clip_name(path: Path) -> str:
    """The file's name without .bvh and .gz: '01_01' for 01_01.bvh.gz."""
    name = path.name[:-3] if path.name.lower().endswith(".gz") else path.name
    return Path(name).stem


def world_transforms(clip: BvhClip, frames: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (F, J, 4) and positions (F, J, 3) of every joint for the selected frames."""
    local_rotation, local_position = clip.rotations[frames], clip.positions[frames]
    rotation = np.empty_like(local_rotation)
    position = np.empty_like(local_position)
    for j, parent in enumerate(clip.parents):
        if parent < 0:
            rotation[:, j] = local_rotation[:, j]
            position[:, j] = local_position[:, j]
        else:
            parent_rotation = Rotation.from_quat(rotation[:, parent])
            rotation[:, j] = (parent_rotation * Rotation.from_quat(local_rotation[:, j])).as_quat()
            position[:, j] = position[:, parent] + parent_rotation.apply(local_position[:, j])
    return rotation, position


def _chain_sums(parents: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """World positions of joints whose rotations are all the identity."""
    world = np.array(offsets, dtype=np.float64)
    for j, parent in enumerate(parents):
        if parent >= 0:
            world[j] += world[parent]
    return world


def _detect_unit_scale(tree: _Tree, offsets: np.ndarray, source: str) -> float:
    """The scale of UNITS that makes the rest pose (joints and End Sites) span closest to TYPICAL_EXTENT."""
    joints = _chain_sums(np.array(tree.parents), offsets)
    points = np.concatenate([joints] + [joints[j] + o[None] for j, o in tree.end_sites.items()])
    extent = float((points.max(axis=0) - points.min(axis=0)).max())
    if not extent > 0:
        raise ValueError(f"{source}: the rest pose has no extent (all OFFSETs are zero); pass an explicit scale")
    return min(UNITS.values(), key=lambda s: abs(np.log(extent * s / TYPICAL_EXTENT)))


class _Tree:
    """The hierarchy as it is parsed: per joint its name, parent, offset and channels ((axis, kind) pairs)."""

    def __init__(self):
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[np.ndarray] = []
        self.channels: list[list[tuple[str, str]]] = []
        self.end_sites: dict[int, np.ndarray] = {}
        self.lines: dict[str, int] = {}     # joint name -> the line it is named on (a linear duplicate check)


def _parse_hierarchy(tokens: _Tokens) -> _Tree:
    """The ROOT block (its keyword already read) and every joint in it, with a stack of the joints still open
    rather than recursion: nesting as deep as MAX_JOINTS stays within Python's stack."""
    tree = _Tree()
    open_joints = [_parse_joint(tokens, tree, -1)]    # innermost last
    while open_joints:
        joint = open_joints[-1]
        word = tokens.word("JOINT, End Site or }")
        if word == "}":
            open_joints.pop()
        elif word == "JOINT":
            open_joints.append(_parse_joint(tokens, tree, joint))
        elif word == "End":
            _parse_end_site(tokens, tree, joint)
        else:
            tokens.fail("expected JOINT, End Site or '}' in a joint")
    return tree


def _parse_joint(tokens: _Tokens, tree: _Tree, parent: int) -> int:
    """One joint's name, OFFSET and CHANNELS (the ROOT or JOINT keyword already read); its index."""
    name = tokens.name()
    if name in tree.lines:
        tokens.fail(f"a joint name appears twice (first on line {tree.lines[name]})")
    if len(tree.names) == MAX_JOINTS:
        tokens.fail(f"more than {MAX_JOINTS} joints")
    tree.lines[name] = tokens.line
    tree.names.append(name)
    tree.parents.append(parent)
    tokens.expect("{")
    tokens.expect("OFFSET")
    tree.offsets.append(np.array([tokens.number("OFFSET value") for _ in range(3)]))
    tokens.expect("CHANNELS")
    tree.channels.append(tokens.channels())
    return len(tree.names) - 1


def _parse_end_site(tokens: _Tokens, tree: _Tree, joint: int) -> None:
    """An End Site block of `joint` (the word End already read)."""
    if joint in tree.end_sites:
        tokens.fail("a joint has a second End Site")
    tokens.expect("Site")
    tokens.expect("{")
    tokens.expect("OFFSET")
    tree.end_sites[joint] = np.array([tokens.number("OFFSET value") for _ in range(3)])
    tokens.expect("}")


_CHANNEL_NAMES = {f"{axis}{kind}".lower(): (axis, kind) for axis in "XYZ" for kind in ("position", "rotation")}


class _Tokens:
    """Whitespace-separated words with their line numbers, read front to back from lines that are taken only as
    far as the words asked for; the motion data is read by line."""

    def __init__(self, lines: Iterable[str], source: str):
        self.source = source
        self.lines = iter(lines)
        self.lines_taken = 0
        self.pending: list[str] = []   # the words of line `lines_taken` not read yet, last word first
        self.line = 1                  # the line of the word read last: the one a problem is found at

    def fail(self, problem: str) -> NoReturn:
        raise ValueError(f"{self.source}:{self.line}: {problem}")

    def word(self, what: str) -> str:
        while not self.pending:
            line = next(self.lines, None)
            if line is None:
                self.fail(f"file ends where {what} was expected")
            self.lines_taken += 1
            self.pending = line.split()[::-1]
        self.line = self.lines_taken
        return self.pending.pop()

    def expect(self, keyword: str) -> None:
        word = self.word(f"'{keyword}'")
        if word.lower() != keyword.lower():
            self.fail(f"expected '{keyword}'")

    def name(self) -> str:
        """A joint name: the words after the keyword on its line, up to an opening brace."""
        parts = []
        while self.pending and self.pending[-1] != "{":
            parts.append(self.pending.pop())
        if not parts:
            self.fail("joint without a name")
        return " ".join(parts)

    def number(self, what: str) -> float:
        """A finite number: NaN and inf would pass every comparison made of them later (a NaN OFFSET once read
        as a rest pose without extent)."""
        try:
            value = float(self.word(what))
        except ValueError:
            self.fail(f"expected a number ({what})")
        if not math.isfinite(value):
            self.fail(f"{what} is not a finite number")
        return value

    def count(self, what: str, minimum: int, maximum: int) -> int:
        value = self.number(what)
        if value != int(value) or not minimum <= value <= maximum:
            self.fail(f"{what} must be a whole number from {minimum} to {maximum:,}, got {value:g}")
        return int(value)

    def channels(self) -> list[tuple[str, str]]:
        n = self.count("channel count", 0, 6)      # each axis once as a position and once as a rotation
        channels = []
        for _ in range(n):
            word = self.word("a channel name")
            if word.lower() not in _CHANNEL_NAMES:
                self.fail("unknown channel name (expected Xposition ... Zrotation)")
            channels.append(_CHANNEL_NAMES[word.lower()])
        for kind in ("position", "rotation"):
            axes = [axis for axis, k in channels if k == kind]
            if axes and sorted(axes) != ["X", "Y", "Z"]:
                self.fail(f"{kind} channels must be all three axes once each, got {''.join(axes)}")
        return channels

    def frames(self, n_frames: int, n_channels: int) -> np.ndarray:
        """The motion data: the lines after 'Frame Time', one frame each with `n_channels` numbers, converted as
        they stream in. A wrong line count is reported before a wrong line, as the file's shape comes first."""
        first = self.line  # the line holding the frame time; data starts on the next
        values = np.empty((n_frames, n_channels))     # bounded by MAX_CLIP_VALUES in the header
        rows, problem = 0, None
        for number, line in enumerate(self.lines, start=self.lines_taken + 1):
            words = line.split()
            if not words:
                continue
            if rows < n_frames and problem is None:
                problem = _fill_row(values[rows], words, f"{self.source}:{number}")
            rows += 1
        if rows != n_frames:
            raise ValueError(f"{self.source}:{first}: 'Frames: {n_frames}' but {rows} data lines follow")
        if problem is not None:
            raise ValueError(problem)
        return values


def _fill_row(row: np.ndarray, words: list[str], where: str) -> str | None:
    """Parse one frame's words into `row`; what is wrong with them, or None."""
    if len(words) != len(row):
        return f"{where}: expected {len(row)} channel values, got {len(words)}"
    try:
        row[:] = [float(w) for w in words]
    except ValueError:
        return f"{where}: a channel value is not a number"
    if not np.isfinite(row).all():
        return f"{where}: a channel value is not finite"
    return None
