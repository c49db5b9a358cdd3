"""Stage `dataset`: one learning problem of paper Table 2 (a task, pipeline/tasks) over a scene's sequences, with a
seeded train/test split of the training sequences and the held-out sequences as a third split.

    python -m pipeline.dataset SUBDIV.h5 OUT.h5 SEQUENCE [SEQUENCE ...] [--settings SETTINGS.json]
                               [--frame world|torso] [--test-fraction 0.1] [--seed 0]
                               [--test-split random|windows] [--test-window 2] [--guard 1]
                               [--task upsampling|pose|pca] [--components K] [--threads N] [--quiet]

A SEQUENCE is a folder holding one sequence's sim_low.h5 and sim_high.h5 and, where there is one, its scene.h5
(results/<scene>/sequences/<name>/, so `results/pants/sequences/*` gathers a scene); a sequence dropped on the way
(a library window that could not be played, a run that tangled) is left out and listed. Its frames follow those of
the sequences before it, in the order given; the frames before its first clip (the settle period: scene.h5
`motion/clip` 0, at rest and alike in every sequence) are kept in the first training sequence only. A folder
without scene.h5 is a training sequence named after the folder, all of whose frames are kept.

The task (default `upsampling`) says what the input and the predictor are; the target is always the displacement
x_high - predictor, all in the reference frame (`world`, or `torso` using each scene.h5's `torso_transforms`).
upsampling: input and predictor are the Loop-subdivided low-res positions S x_low (every row of S sums to one, so
S commutes with the rigid change of frame: S (R x + t) = R S x + t), stored as the low-res run in the reference
frame and S, never multiplied out (pipeline.artifacts.dataset); pose: the mannequin's 208 pose scalars over linear blend skinning;
pca: K (--components) PCA coefficients of the high-res run over its PCA reconstruction.

The test frames are a seeded share of the training sequences' frames: random frames (`--test-split random`, the
paper's way; most then have a trained neighbour a frame away, so the test measures interpolation), or
(`windows`) contiguous blocks of up to --test-window seconds (split_windows), and the frames within --guard
seconds of a test frame, in its sequence's run or in its library file's motion, are in no split: no frame trained
on lies near a tested one. Every frame of a held-out sequence (scene.h5 attr `role`) is held out, a third split
that measures generalisation to an unseen motion. Garment scenes also get each frame's mannequin (skeleton, body
state, capsules, pose, torso transforms) under scene.h5's names, and every frame the direction of gravity (and the
body's capsules) in the reference frame, under `context/`: what the network's body- and gravity-relative inputs
are made from. docs/artifacts.md lists every dataset.
With --settings (a scene's resolved settings.json), `dataset.frame`, `dataset.test_fraction`, `dataset.seed`,
`dataset.test_split`, `dataset.test_window` and `dataset.guard` are the defaults of the flags of those names.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import sys
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence, TypeVar

import numpy as np

from pipeline.artifacts.dataset import (RANDOM, WINDOWS, DatasetLayout, Split, SplitRule, count_test_frames,
                                       split_frames, write_dataset)
from pipeline.artifacts.scene import (CAPSULE_A, CAPSULE_B, read_library_window, read_mannequin_frames, read_sequence,
                                      read_torso_transforms)
from pipeline.artifacts.simulation import RunPhysics, read_run_outline, read_run_physics, read_trajectory
from pipeline.artifacts.subdiv import Subdivision, read_subdivision
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import check_same_mesh, dropped_reason, source_mesh_of
from pipeline.tasks import TASKS, task_of
from pipeline.tasks.task import DatasetRequest, SequenceRun, in_reference_frames
from scenes.sequences import HELD_OUT, TRAIN

SCENE, SIM_LOW, SIM_HIGH = "scene.h5", "sim_low.h5", "sim_high.h5"
Item, Result, Prepared = TypeVar("Item"), TypeVar("Result"), TypeVar("Prepared")


@dataclasses.dataclass(frozen=True)
class SequenceSource:
    """A sequence folder as the dataset uses it: which frames it keeps (from `first` on) and its role."""
    folder: Path
    name: str
    role: str                  # train or held_out
    n_frames: int
    first: int                 # first frame kept: 0, or the end of the settle period
    clips: tuple[str, ...]     # the clips it plays, in order (none without a mannequin)
    scene: Path | None         # its scene.h5, if it has one
    window: dict | None = None     # the motion library window it plays (scene.h5 attr library_window), if any
    settle: int = 0                # frames before its first clip (the settle period; a library window's hold too)

    @property
    def kept(self) -> int:
        return self.n_frames - self.first


# A clock of the frames: per frame a key (frames of one key share a timeline; -1: on no timeline of this clock)
# and the frame's time on it, in frames.
Clock = tuple[np.ndarray, np.ndarray]


def block_frames(window: float, frame_time: float) -> int:
    """Frames of a test block of `window` seconds (at least one)."""
    return max(1, int(round(window / frame_time)))


def guard_frames(guard: float, frame_time: float) -> int:
    """The most frames two frames may lie apart and still be within `guard` seconds of each other; a guard a
    whole number of frames long to a millionth of a frame is taken as that many (a stored time step such as
    0.0166666667 s would otherwise make 1 s 59 frames, and frames 1.000000002 s apart count as farther)."""
    return int(np.floor(guard / frame_time + 1e-6))


def split_windows(sequence: np.ndarray, clocks: Sequence[Clock], test_fraction: float, block: int, guard: int,
                  seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded test blocks of consecutive frames: each sequence (a run of equal `sequence` ids) is cut into slots
    (block_slots); slots drawn in a seeded order are test, whole, until they hold count_test_frames(...) frames,
    the last one drawn only in part (a seeded stretch of it). So blocks never cross sequences and a sequence
    shorter than `block` frames (a library window shorter than the test window) is tested whole. A frame within
    `guard` frames of a test frame on any of the `clocks` is guard (in no split), the others train. Returns the
    sorted positions of the train, test and guard frames."""
    n_test = count_test_frames(len(sequence), test_fraction)
    starts, lengths = block_slots(sequence, block)
    rng = np.random.default_rng(seed)
    drawn = rng.permutation(len(starts))
    held = np.cumsum(lengths[drawn])
    drawn = drawn[:int(np.searchsorted(held, n_test)) + 1]       # the fewest that hold n_test frames
    taken = lengths[drawn].copy()
    taken[-1] -= int(taken.sum()) - n_test
    offsets = np.zeros(len(drawn), np.int64)
    offsets[-1] = rng.integers(0, lengths[drawn[-1]] - taken[-1] + 1)
    is_test = np.zeros(len(sequence), bool)
    for start, count in zip(starts[drawn] + offsets, taken):
        is_test[start:start + count] = True
    is_guard = np.logical_or.reduce([near_test(key, time, is_test, guard) for key, time in clocks]) & ~is_test
    train = np.flatnonzero(~is_test & ~is_guard)
    if not len(train):
        raise PipelineError("test split 'windows': every training frame is test or within dataset.guard (--guard) "
                            "of one: lower the guard or dataset.test_fraction")
    return train, np.flatnonzero(is_test), np.flatnonzero(is_guard)


def block_slots(sequence: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """The first positions and lengths of the slots a windows split draws its test blocks from: each sequence (a
    run of equal `sequence` ids) cut into the fewest slots of at most `block` frames, of lengths differing by one
    frame at most (the longer first)."""
    firsts = np.flatnonzero(np.r_[True, sequence[1:] != sequence[:-1]])
    starts, lengths = [], []
    for first, end in zip(firsts, np.r_[firsts[1:], len(sequence)]):
        count = -(-(end - first) // block)
        sizes = (end - first) // count + (np.arange(count) < (end - first) % count)
        starts.append(first + np.r_[0, np.cumsum(sizes)[:-1]])
        lengths.append(sizes)
    return np.concatenate(starts), np.concatenate(lengths)


def near_test(key: np.ndarray, time: np.ndarray, is_test: np.ndarray, reach: int) -> np.ndarray:
    """Whether each frame lies at most `reach` from a test frame of its key on a clock (key -1: from none)."""
    near = np.zeros(len(key), bool)
    for timeline in np.unique(key[is_test & (key >= 0)]):
        mine = np.flatnonzero(key == timeline)
        tests = np.sort(time[mine][is_test[mine]])
        at = np.searchsorted(tests, time[mine])
        gap = np.minimum(np.abs(time[mine] - tests[np.maximum(at - 1, 0)]),
                         np.abs(tests[np.minimum(at, len(tests) - 1)] - time[mine]))
        near[mine] = gap <= reach
    return near


def frame_clocks(sources: list[SequenceSource], frame_time: float) -> list[Clock]:
    """The clocks of the sequences' kept frames: each sequence's run (its frame index), and each library file's
    motion, on which a window's frames lie at its start plus the frames since its clip began (the blend into its
    first pose and the hold count as its start). Windows of one take share a clock: a test block at the end of one
    window makes the start of the next, the same motion a frame later, guard."""
    run = (np.concatenate([np.full(s.kept, k) for k, s in enumerate(sources)]),
           np.concatenate([np.arange(s.first, s.n_frames) for s in sources]))
    files: dict[str, int] = {}
    keys, times = [], []
    for source in sources:
        frames = np.arange(source.first, source.n_frames)
        if source.window is None:
            keys.append(np.full(source.kept, -1))
            times.append(np.zeros(source.kept, np.int64))
            continue
        start = source.window.get("start")
        if not isinstance(start, (int, float)) or not np.isfinite(start) or start < 0:
            raise PipelineError(f"{source.scene}: attr 'library_window' has no start (seconds >= 0)")
        keys.append(np.full(source.kept, files.setdefault(source.window["file"], len(files))))
        times.append(int(round(start / frame_time)) + np.maximum(frames - source.settle, 0))
    return [run, (np.concatenate(keys), np.concatenate(times))]


def find_sequences(folders: Sequence[str]) -> tuple[list[SequenceSource], list[tuple[str, str]]]:
    """The sequences of the given folders, in order, with the frames each keeps (see the module docstring), and
    (name, reason) of each sequence dropped on the way (a library window that could not be played, a run that
    tangled: pipeline.core.h5.write_dropped), which the dataset passes over."""
    sources, dropped, settle_kept = [], [], False
    for folder in map(Path, folders):
        scene = folder / SCENE if (folder / SCENE).is_file() else None
        reason = next((f"{name}: {why}" for name in (SCENE, SIM_LOW, SIM_HIGH) if (folder / name).is_file()
                       and (why := dropped_reason(folder / name))), "")
        if reason:
            dropped.append((folder.name, reason))
            continue
        n_frames, _ = read_run_outline(folder / SIM_LOW)
        if scene is None:
            sources.append(SequenceSource(folder, folder.name, TRAIN, n_frames, 0, (), None))
            continue
        info = read_sequence(scene)
        if info.n_frames != n_frames:
            raise PipelineError(f"{scene}: {info.n_frames} frames, but {folder / SIM_LOW} has {n_frames}")
        keep_settle = info.role == TRAIN and not settle_kept
        settle_kept = settle_kept or keep_settle
        sources.append(SequenceSource(folder, info.name, info.role, n_frames, 0 if keep_settle else info.settle_frames,
                                      info.clip_names[1:], scene, read_library_window(scene), info.settle_frames))
    names = [s.name for s in sources]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise PipelineError(f"sequence '{repeated[0]}' is given twice ({', '.join(str(s.folder) for s in sources)})")
    if not any(s.role == TRAIN for s in sources):
        raise PipelineError(f"no training sequence among {', '.join(map(str, folders))} (all are held out or "
                            f"dropped)")
    return sources, dropped


def shared_physics(sources: list[SequenceSource]) -> RunPhysics:
    """The time step and gravity all the sequences' runs were made with; an error naming a run that differs
    (velocities and the gravity input would mean different things across frames)."""
    runs = [(source.folder / SIM_LOW, read_run_physics(source.folder / SIM_LOW)) for source in sources]
    first_path, first = runs[0]
    for path, physics in runs[1:]:
        if not (np.isclose(physics.dt, first.dt, rtol=1e-9) and np.allclose(physics.gravity, first.gravity)):
            raise PipelineError(f"{path}: made with dt {physics.dt:g} s and gravity {physics.gravity.tolist()}, "
                                f"{first_path} with {first.dt:g} s and {first.gravity.tolist()}")
    return first


def dataset_layout(sources: list[SequenceSource], subdivision: Subdivision, low_faces: np.ndarray, frame: str,
                   test_fraction: float, seed: int, frame_time: float, dropped: Sequence[tuple[str, str]] = (),
                   test_split: SplitRule = SplitRule()) -> DatasetLayout:
    """Where every frame comes from, and the split: of the training sequences' frames a seeded share is test
    (random frames, or contiguous blocks with their guard frames in no split: `test_split`), the rest train;
    every frame of the held-out sequences is held out."""
    sequence = np.concatenate([np.full(s.kept, k) for k, s in enumerate(sources)])
    sequence_frame = np.concatenate([np.arange(s.first, s.n_frames) for s in sources])
    held = np.isin(sequence, [k for k, s in enumerate(sources) if s.role == HELD_OUT])
    seen = np.flatnonzero(~held)
    guard = np.zeros(0, np.int64)
    if test_split.kind == WINDOWS:
        clocks = [(key[seen], time[seen]) for key, time in frame_clocks(sources, frame_time)]
        train, test, guard = split_windows(sequence[seen], clocks, test_fraction,
                                           block_frames(test_split.window, frame_time),
                                           guard_frames(test_split.guard, frame_time), seed)
    else:
        train, test = split_frames(len(seen), test_fraction, seed)
    held_clips = tuple(dict.fromkeys(c for s in sources if s.role == HELD_OUT for c in s.clips))
    return DatasetLayout(
        faces=subdivision.faces, rest_vertices=subdivision.vertices, low_faces=low_faces,
        n_low_vertices=subdivision.S.shape[1], sequence=sequence, sequence_frame=sequence_frame,
        names=tuple(s.name for s in sources), roles=tuple(s.role for s in sources),
        clips=tuple(",".join(s.clips) for s in sources),
        split=Split(seen[train], seen[test], np.flatnonzero(held), held_clips, seen[guard], test_split),
        frame=frame, seed=seed, test_fraction=test_fraction, frame_time=frame_time,
        windows=tuple(s.window for s in sources), dropped=tuple(dropped), subdivision=subdivision.S)


def read_run(source: SequenceSource, subdivision: Subdivision, low_faces: np.ndarray, frame: str,
             physics: RunPhysics) -> SequenceRun:
    """A sequence's kept frames in the reference frame, with gravity (`physics`, world frame) and the body's
    capsules; raises PipelineError naming the file that does not fit the others (the subdivision, and the
    low-res faces of the first sequence)."""
    low_path, high_path = source.folder / SIM_LOW, source.folder / SIM_HIGH
    low_run, high_run = read_trajectory(low_path), read_trajectory(high_path)
    low, high = low_run.positions[source.first:], high_run.positions[source.first:]
    S = subdivision.S
    if S.shape != (high.shape[1], low.shape[1]):
        raise PipelineError(f"{high_path}: {high.shape[1]} vertices and {low_path} {low.shape[1]}, but the "
                            f"subdivision S is {S.shape}")
    for path, faces, expected in ((low_path, low_run.faces, low_faces), (high_path, high_run.faces, subdivision.faces)):
        if faces.shape != expected.shape or not np.array_equal(faces, expected):
            raise PipelineError(f"{path}: its faces differ from the other sequences' or the subdivision's: not "
                                f"the same mesh")
    if len(high_run.positions) != source.n_frames:
        raise PipelineError(f"{high_path}: {len(high_run.positions)} frames but {low_path} has {source.n_frames}")
    mannequin = read_mannequin_frames(source.scene, source.first) if source.scene is not None else None
    capsules = None if mannequin is None else (mannequin.per_frame[CAPSULE_A], mannequin.per_frame[CAPSULE_B])
    gravity = np.repeat(physics.gravity[None] / np.linalg.norm(physics.gravity), len(low), axis=0)
    transforms = None
    if frame == "torso":
        if source.scene is None:
            raise PipelineError(f"{source.folder}: --frame torso needs the sequence's {SCENE} (torso_transforms)")
        transforms = read_torso_transforms(source.scene, source.n_frames)[source.first:]
        low, high = in_reference_frames(transforms, low), in_reference_frames(transforms, high)
        gravity = np.einsum("fji,fj->fi", transforms[:, :3, :3], gravity)      # R^T g: a direction turns only
        if capsules is not None:
            capsules = tuple(in_reference_frames(transforms, ends) for ends in capsules)
    return SequenceRun(source.scene or source.folder, low, high, transforms, gravity, mannequin, capsules)


def prepared_in_order(sources: list[SequenceSource], subdivision: Subdivision, low_faces: np.ndarray, frame: str,
                      physics: RunPhysics, prepare: Callable[[SequenceRun], Prepared],
                      threads: int) -> Iterator[Prepared]:
    """`prepare` of each sequence's run, in dataset order; all runs with a mannequin or none. Reading a run and
    preparing it is most of the stage's work, and numpy and HDF5 reads of whole arrays leave the GIL to the other
    threads: `threads` sequences are read and prepared at once while the caller takes the earlier ones in turn."""
    def read_and_prepare(source: SequenceSource) -> tuple[Path, bool, Prepared]:
        run = read_run(source, subdivision, low_faces, frame, physics)   # let go once prepared: memory
        return run.where, run.mannequin is not None, prepare(run)

    with_body = None
    for where, has_body, prepared in in_order(read_and_prepare, sources, threads):
        if with_body is not None and has_body != with_body:
            raise PipelineError(f"{where}: some sequences have a mannequin and some not")
        with_body = has_body
        yield prepared


def in_order(work: Callable[[Item], Result], items: Sequence[Item], threads: int) -> Iterator[Result]:
    """work(item) of each item, done on `threads` threads and yielded in the items' order. At most `threads` items
    are taken ahead of the one the caller waits for, so only that many sequences are held in memory at once; the
    first item (in order) whose work fails raises its error, as a loop would, and the work not yet started is
    dropped."""
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending: collections.deque[Future] = collections.deque()
        try:
            for item in items:
                pending.append(pool.submit(work, item))
                if len(pending) > threads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()


def flags_from_settings(settings: dict) -> dict[str, Any]:
    dataset = settings["dataset"]
    return {"frame": dataset["frame"], "test_fraction": dataset["test_fraction"], "seed": dataset["seed"],
            "test_split": dataset["test_split"], "test_window": dataset["test_window"], "guard": dataset["guard"]}


def windows_notes(layout: DatasetLayout, sources: list[SequenceSource]) -> list[str]:
    """What a reader of a windows split should know: the training sequences left with no frame to train on, and
    how many frames the test and the guard take."""
    rule, split = layout.split.test_split, layout.split
    trained = np.bincount(layout.sequence[split.train], minlength=len(sources))
    notes = [f"sequence {s.name}: all {s.kept} of its frames are test or guard (within {rule.guard:g} s of a test "
             f"frame): none is trained on" for k, s in enumerate(sources) if s.role == TRAIN and not trained[k]]
    test = split.test
    blocks = 1 + np.sum((np.diff(test) != 1) | (np.diff(layout.sequence[test]) != 0))
    notes.append(f"test split 'windows': {len(split.test)} test frames in {blocks} stretch(es) of consecutive frames "
                 f"(blocks of up to {block_frames(rule.window, layout.frame_time)} frames, {rule.window:g} s); "
                 f"{len(split.guard)} guard frames (within {rule.guard:g} s of a test frame) in neither train nor test")
    return notes


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.dataset", description=__doc__.splitlines()[0])
    parser.add_argument("subdiv"), parser.add_argument("out", help="dataset.h5 to write")
    parser.add_argument("sequences", nargs="+", metavar="SEQUENCE",
                        help="folders holding a sequence's sim_low.h5, sim_high.h5 and (if it has one) scene.h5")
    parser.add_argument("--frame", choices=["world", "torso"], default="world",
                        help="reference frame of all positions (torso needs each sequence's scene.h5)")
    parser.add_argument("--test-fraction", type=float, default=0.1,
                        help="share of the training sequences' frames held out as test (paper: 0.1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the train/test split")
    parser.add_argument("--test-split", choices=[RANDOM, WINDOWS], default=RANDOM,
                        help="test frames drawn at random (the paper's), or as contiguous blocks (windows) with no "
                             "frame trained on within --guard seconds of one")
    parser.add_argument("--test-window", type=float, default=2.0,
                        help="windows: the longest test block, in seconds (a shorter sequence is tested whole)")
    parser.add_argument("--guard", type=float, default=1.0,
                        help="windows: seconds around each test frame in which no frame is trained on")
    parser.add_argument("--task", choices=list(TASKS), default="upsampling",
                        help="the learning problem: its input and predictor (pipeline/tasks)")
    parser.add_argument("--components", type=int, help="PCA components (task pca)")
    parser.add_argument("--threads", type=int, default=1,
                        help="sequences read and prepared at once, beside the thread writing the dataset (Snakemake: "
                             "the rule's threads); the dataset is the same for any number")
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings, unread=LEARNING_ONLY)
    if not 0 < args.test_fraction < 1:
        raise PipelineError(f"--test-fraction must lie in (0, 1), got {args.test_fraction}")
    if not (np.isfinite(args.test_window) and np.isfinite(args.guard) and args.test_window > 0 and args.guard >= 0):
        raise PipelineError(f"--test-window must be > 0 and --guard >= 0 seconds, got {args.test_window} and "
                            f"{args.guard}")
    if args.threads < 1:
        raise PipelineError(f"--threads {args.threads}: give at least 1")
    if (args.components is not None) != (args.task == "pca") or (args.components is not None and args.components < 1):
        raise PipelineError("--components K >= 1 goes with --task pca, and only with it")
    task = task_of(args.task, "--task")
    subdivision = read_subdivision(args.subdiv)
    sources, dropped = find_sequences(args.sequences)
    for name, reason in dropped:
        print(f"dataset: sequence {name} left out: {reason}", file=sys.stderr)
    for source in sources:      # equal vertex counts are not enough: the runs must be of the mesh S subdivides
        for run in (SIM_LOW, SIM_HIGH):
            check_same_mesh(args.subdiv, source.folder / run)
    low_faces = read_run_outline(sources[0].folder / SIM_LOW)[1]
    physics = shared_physics(sources)
    rule = SplitRule(WINDOWS, args.test_window, args.guard) if args.test_split == WINDOWS else SplitRule()
    layout = dataset_layout(sources, subdivision, low_faces, args.frame, args.test_fraction, args.seed,
                            physics.dt, dropped, rule)
    if rule.kind == WINDOWS:
        for note in windows_notes(layout, sources):
            print(f"dataset: {note}", file=sys.stderr)
    def prepared(prepare: Callable[[SequenceRun], Prepared]) -> Iterator[Prepared]:
        return prepared_in_order(sources, subdivision, low_faces, args.frame, physics, prepare, args.threads)

    def runs() -> Iterator[SequenceRun]:      # a task's own pass over them (PCA fits its basis to them)
        return prepared(lambda run: run)

    task_layout, make_frames = task.prepare(DatasetRequest(layout, subdivision, runs, sources[0].scene,
                                                           args.components))
    layout = dataclasses.replace(layout, task=task_layout)
    # The upsampling's random split records what it always did; a windows split adds its settings, another task
    # its name and settings.
    names = ("subdiv", "sequences", "frame", "test_fraction", "seed")
    names += ("test_split", "test_window", "guard") if rule.kind == WINDOWS else ()
    config = {name: getattr(args, name) for name in names + (() if task_layout is None else ("task", "components"))}
    write_dataset(args.out, config, layout, prepared(make_frames), source_mesh_of(args.subdiv))
    if not args.quiet:
        split = layout.split
        guard = f", {len(split.guard)} guard" if rule.kind == WINDOWS else ""
        print(f"dataset ({args.task}): {len(layout.sequence)} frames of {len(sources)} sequence(s) "
              f"({len(split.train)} train, {len(split.test)} test, {len(split.held_out)} held out{guard}) of "
              f"{len(layout.rest_vertices)} vertices, {args.frame} frame -> {args.out}")


if __name__ == "__main__":
    cli.run(main)
