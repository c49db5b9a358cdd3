"""Stage `dataset`: the cloth-upsampling learning problem of paper Table 2, with a seeded train/test split.

    python -m pipeline.dataset SIM_LOW.h5 SIM_HIGH.h5 SUBDIV.h5 OUT.h5 [--settings SETTINGS.json]
                               [--frame world|torso] [--scene SCENE.h5] [--test-fraction 0.1]
                               [--test-clips walk,...] [--seed 0] [--quiet]

Input and predictor: the Loop-subdivided low-res positions S x_low; target: the displacement x_high - S x_low;
all in the scene's reference frame (`world`, or `torso` using SCENE.h5's `torso_transforms`). Because every row
of S sums to one, S commutes with the rigid change of frame. The test frames are a seeded random share of the
frames; with --test-clips every frame of those mannequin clips (SCENE.h5 `motion/clip`) is held out as well, in
a third split that measures generalisation to an unseen motion. docs/artifacts.md lists every dataset.
With --settings (a scene's resolved settings.json), `dataset.frame`, `dataset.test_fraction` and `dataset.seed` are
the defaults of --frame, --test-fraction and --seed, and when `dataset.split` is `held_out`,
`drivers.mannequin.test_clips` is that of --test-clips.
"""
from __future__ import annotations

import argparse
from typing import Any, Sequence

import numpy as np

from geometry.rigid import apply_rigid_inverse
from pipeline import cli
from pipeline.artifacts.dataset import Split, UpsamplingProblem, write_dataset
from pipeline.artifacts.scene import read_clips, read_torso_transforms
from pipeline.artifacts.simulation import read_trajectory
from pipeline.artifacts.subdiv import read_subdivision
from pipeline.errors import PipelineError


def split_frames(n_frames: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split: sorted train and test frame ids, at least one frame in each."""
    if n_frames < 2:
        raise PipelineError(f"a train/test split needs at least 2 frames, got {n_frames}")
    n_test = min(max(1, int(round(test_fraction * n_frames))), n_frames - 1)
    order = np.random.default_rng(seed).permutation(n_frames)
    return np.sort(order[n_test:]), np.sort(order[:n_test])


def held_out_frames(scene_path: str | None, n_frames: int, test_clips: list[str]) -> np.ndarray:
    """Sorted ids of the frames that belong to the mannequin clips `test_clips`."""
    if scene_path is None:
        raise PipelineError("--test-clips needs --scene SCENE.h5 holding 'motion/clip' and 'motion/clip_names'")
    clip, names = read_clips(scene_path)
    if len(clip) != n_frames:
        raise PipelineError(f"{scene_path}: 'motion/clip' has {len(clip)} frames, the simulation {n_frames}")
    unknown = sorted(set(test_clips) - set(names))
    if unknown:
        raise PipelineError(f"{scene_path}: no clip '{unknown[0]}' in this scene's motion (clips: {', '.join(names)})")
    held = np.isin(clip, [names.index(n) for n in test_clips])
    if n_frames - held.sum() < 2 or not held.any():
        raise PipelineError(f"--test-clips {','.join(test_clips)} leaves {n_frames - held.sum()} frames to train "
                            f"and test on and {held.sum()} held out")
    return np.flatnonzero(held)


def split_dataset(n_frames: int, test_fraction: float, seed: int, held_out: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Train, test and held-out frame ids: the held-out frames aside, a seeded random share of the rest is test."""
    seen = np.setdiff1d(np.arange(n_frames), held_out)
    train, test = split_frames(len(seen), test_fraction, seed)
    return seen[train], seen[test], np.asarray(held_out, dtype=np.int64)


def _torso_transforms(scene_path: str | None, n_frames: int) -> np.ndarray:
    if scene_path is None:
        raise PipelineError("--frame torso needs --scene SCENE.h5 holding the 'torso_transforms' dataset")
    return read_torso_transforms(scene_path, n_frames)


def build_dataset(low_path: str, high_path: str, subdiv_path: str, frame: str,
                  scene_path: str | None) -> UpsamplingProblem:
    """Arrays of the learning problem; raises PipelineError naming the file that does not fit the others."""
    low_run, high_run = read_trajectory(low_path), read_trajectory(high_path)
    low, high = low_run.positions, high_run.positions
    mesh = read_subdivision(subdiv_path)
    subdivision = mesh.S
    if subdivision.shape != (high.shape[1], low.shape[1]):
        raise PipelineError(f"{subdiv_path}: S is {subdivision.shape} but {high_path} has {high.shape[1]} and "
                            f"{low_path} {low.shape[1]} vertices")
    if high_run.faces.shape != mesh.faces.shape or not np.array_equal(high_run.faces, mesh.faces):
        raise PipelineError(f"{high_path}: its faces differ from {subdiv_path}'s: not the same high-res mesh")
    if len(low) != len(high):
        raise PipelineError(f"{high_path}: {len(high)} frames but {low_path} has {len(low)}")
    transforms = _torso_transforms(scene_path, len(low)) if frame == "torso" else None
    if transforms is not None:
        low = apply_rigid_inverse(transforms[:, None], low)
        high = apply_rigid_inverse(transforms[:, None], high)
    subdivided = np.stack([subdivision @ x for x in low])
    return UpsamplingProblem(subdivided.astype(np.float32), (high - subdivided).astype(np.float32), mesh.faces,
                             mesh.vertices, low.astype(np.float32), low_run.faces)


def flags_from_settings(settings: dict) -> dict[str, Any]:
    dataset = settings["dataset"]
    held_out = dataset["split"] == "held_out"
    return {"frame": dataset["frame"], "test_fraction": dataset["test_fraction"], "seed": dataset["seed"],
            "test_clips": settings["drivers"]["mannequin"]["test_clips"] if held_out else None}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.dataset", description=__doc__.splitlines()[0])
    parser.add_argument("sim_low"), parser.add_argument("sim_high"), parser.add_argument("subdiv")
    parser.add_argument("out", help="dataset.h5 to write")
    parser.add_argument("--frame", choices=["world", "torso"], default="world",
                        help="reference frame of all positions (torso needs --scene with torso_transforms)")
    parser.add_argument("--scene", help="scene.h5 (read for --frame torso)")
    parser.add_argument("--test-fraction", type=float, default=0.1, help="share of frames held out (paper: 0.1)")
    parser.add_argument("--test-clips", help="comma-separated motion clips held out as the test set (needs --scene)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the train/test split")
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    if not 0 < args.test_fraction < 1:
        raise PipelineError(f"--test-fraction must lie in (0, 1), got {args.test_fraction}")
    problem = build_dataset(args.sim_low, args.sim_high, args.subdiv, args.frame, args.scene)
    n_frames = len(problem.inputs)
    test_clips = [c.strip() for c in (args.test_clips or "").split(",") if c.strip()]
    held = held_out_frames(args.scene, n_frames, test_clips) if test_clips else np.zeros(0, np.int64)
    train, test, held = split_dataset(n_frames, args.test_fraction, args.seed, held)
    config = {name: getattr(args, name) for name in ("sim_low", "sim_high", "subdiv", "frame", "scene",
                                                    "test_fraction", "test_clips", "seed")}
    write_dataset(args.out, config, problem, Split(train, test, held, tuple(test_clips)), args.frame, args.seed,
                  args.test_fraction)
    if not args.quiet:
        print(f"dataset: {n_frames} frames ({len(train)} train, {len(test)} test, {len(held)} held out) of "
              f"{problem.inputs.shape[1]} vertices, {args.frame} frame -> {args.out}")


if __name__ == "__main__":
    cli.run(main)
