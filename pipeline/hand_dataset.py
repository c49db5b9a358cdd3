"""Stage `hand_dataset`: the hand scene's learning problem (pipeline/tasks/hand.py) as dataset.h5
(pipeline/artifacts/dataset.py's layout, task `hand`): per frame the 18 joint angles (input), linear blend
skinning of the rest skin (the predictor, world frame) and the FEM's skin less it (the target), over the
sequences' FEM runs, with a seeded random share of the training sequences' frames as test and every frame of the
held-out sequences (the fist: a motion of a kind never trained on) as a third split.

CLI: `python -m pipeline.hand_dataset HAND.h5 OUT.h5 SEQUENCE [SEQUENCE ...] [--settings SETTINGS.json]
[--test-fraction 0.1] [--seed 0] [--frame-time DT] [--quiet]`: a SEQUENCE is a folder
results/<scene>/sequences/<name>/ holding fem.h5, its role from its name (train_..., held_out_...), the training
ones first. `dataset.test_fraction`, `dataset.seed` and `solver.dt` (--frame-time) of --settings are the flags'
defaults. The FEM's median ms a frame (after the first two frames: compiling, the first motion) is stored with it
(attr fem_ms_per_frame): the report's speedup.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from pipeline.artifacts.dataset import DatasetLayout, SequenceFrames, Split, TaskLayout, split_frames, write_dataset
from pipeline.artifacts.hand import HandRun, read_hand, read_hand_run
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import check_same_mesh, source_mesh_of
from pipeline.tasks.hand import FEM_DEVICE, FEM_MS, FEM_WORLDS, HandTask
from scenes.hand_shape import Hand
from scenes.hand_skeleton import ANGLE_NAMES, hand_transforms
from scenes.sequences import HELD_OUT, sequence_role

RUN = "fem.h5"
GRAVITY = np.array([0.0, -1.0, 0.0], np.float32)   # y up; the quasi-static hand carries no weight (context only)


def skinned(hand: Hand, angles: np.ndarray) -> np.ndarray:
    """(F, S, 3) the skin by linear blend skinning at each frame's angles (F, 18): the predictor."""
    return hand.skinned(hand_transforms(hand.skeleton, angles))


def sequence_frames(hand: Hand, run: HandRun) -> SequenceFrames:
    predictor = skinned(hand, run.angles)
    n = len(run.angles)
    return SequenceFrames(run.angles.astype(np.float32), (run.skin - predictor).astype(np.float32), None,
                          np.repeat(GRAVITY[None], n, axis=0), None, None, predictor.astype(np.float32))


def fem_cost(runs: list[tuple[str, HandRun]]) -> dict:
    """The FEM's median ms a hand-frame over the runs (frames 2 on), its device and batch size: attrs the report
    reads (pipeline.tasks.hand)."""
    ms = np.concatenate([run.solve_ms[2:] for _, run in runs])
    return {FEM_MS: float(np.median(ms)) if len(ms) else 0.0, FEM_DEVICE: runs[0][1].device,
            FEM_WORLDS: int(max(run.worlds for _, run in runs))}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.hand_dataset", description=__doc__.splitlines()[0])
    parser.add_argument("hand", help="hand.h5 (pipeline.hand_scene)")
    parser.add_argument("out", help="dataset.h5 to write")
    parser.add_argument("sequences", nargs="+", metavar="SEQUENCE", help="folders holding a sequence's fem.h5")
    parser.add_argument("--test-fraction", type=float, default=0.1,
                        help="share of the training sequences' frames held out as test (paper: 0.1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the train/test split")
    parser.add_argument("--frame-time", type=float, default=1 / 60, help="seconds between frames (solver.dt)")
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, lambda s: {"test_fraction": s["dataset"]["test_fraction"],
                                                            "seed": s["dataset"]["seed"],
                                                            "frame_time": s["solver"]["dt"]}, unread=LEARNING_ONLY)
    if not 0 < args.test_fraction < 1:
        raise PipelineError(f"--test-fraction must lie in (0, 1), got {args.test_fraction}")
    if not (np.isfinite(args.frame_time) and args.frame_time > 0):
        raise PipelineError(f"--frame-time must be > 0 seconds, got {args.frame_time}")
    hand = read_hand(args.hand)
    folders = [Path(folder) for folder in args.sequences]
    names = [folder.name for folder in folders]
    try:
        roles = [sequence_role(name) for name in names]
    except ValueError as err:
        raise PipelineError(f"{err}") from None
    if len(set(names)) != len(names) or HELD_OUT == roles[0] or roles != sorted(roles, key=lambda r: r == HELD_OUT):
        raise PipelineError(f"sequences {', '.join(names)}: each once, the training ones first, then the held-out")
    # Planned from the runs' angles and timings alone; their skins (120 MB a 300-frame run at the paper's size) are
    # read one run at a time as the dataset is written.
    runs = []
    for folder in folders:
        check_same_mesh(args.hand, folder / RUN)
        runs.append((folder.name, read_hand_run(folder / RUN, len(hand.skin_vertices), skin=False)))
    counts = [len(run.angles) for _, run in runs]
    sequence = np.concatenate([np.full(n, k) for k, n in enumerate(counts)])
    held = np.isin(sequence, [k for k, role in enumerate(roles) if role == HELD_OUT])
    seen = np.flatnonzero(~held)
    train, test = split_frames(len(seen), args.test_fraction, args.seed)
    held_motions = tuple(name for name, role in zip(names, roles) if role == HELD_OUT)
    task = TaskLayout(HandTask.name, len(ANGLE_NAMES), "joint angles to hand skin (paper Table 4, hand)",
                      f"the hand's 18 joint angles per frame (F, 18), radians: {', '.join(ANGLE_NAMES)}",
                      "linear blend skinning of the rest skin by the hand's bones, per frame (F, S, 3), world frame",
                      attrs=fem_cost(runs))
    layout = DatasetLayout(
        faces=hand.skin_faces, rest_vertices=hand.skin_vertices, low_faces=np.zeros((0, 3), np.int64),
        n_low_vertices=0, sequence=sequence, sequence_frame=np.concatenate([np.arange(n) for n in counts]),
        names=tuple(names), roles=tuple(roles), clips=tuple("" for _ in names),
        split=Split(seen[train], seen[test], np.flatnonzero(held), held_motions), frame="world", seed=args.seed,
        test_fraction=args.test_fraction, frame_time=args.frame_time, task=task)

    def frames() -> Iterator[SequenceFrames]:
        for folder in folders:
            yield sequence_frames(hand, read_hand_run(folder / RUN, len(hand.skin_vertices)))

    config = {"hand": args.hand, "sequences": args.sequences, "test_fraction": args.test_fraction,
              "seed": args.seed, "frame_time": args.frame_time, "task": HandTask.name}
    write_dataset(args.out, config, layout, frames(), source_mesh_of(args.hand))
    if not args.quiet:
        print(f"hand_dataset: {len(sequence)} frames of {len(runs)} sequence(s) ({len(train)} train, {len(test)} "
              f"test, {int(held.sum())} held out) of {len(hand.skin_vertices)} vertices -> {args.out}",
              file=sys.stderr)


if __name__ == "__main__":
    cli.run(main)
