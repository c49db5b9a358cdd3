"""Stage `dataset`: the cloth-upsampling learning problem of paper Table 2, with a seeded train/test split.

    python -m pipeline.dataset SIM_LOW.h5 SIM_HIGH.h5 SUBDIV.h5 OUT.h5 [--frame world|torso] [--scene SCENE.h5]
                               [--test-fraction 0.1] [--test-clips walk,...] [--seed 0] [--quiet]

Input and predictor: the Loop-subdivided low-res positions S x_low; target: the displacement x_high - S x_low;
all in the scene's reference frame (`world`, or `torso` using SCENE.h5's `torso_transforms`). Because every row
of S sums to one, S commutes with the rigid change of frame. The test frames are a seeded random share of the
frames; with --test-clips every frame of those mannequin clips (SCENE.h5 `motion/clip`) is held out as well, in
a third split that measures generalisation to an unseen motion. docs/artifacts.md lists every dataset.
"""
from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np

from geometry.rigid import apply_rigid_inverse
from pipeline import cli
from pipeline.artifacts.h5 import atomic_h5, open_artifact, read, read_csr
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
    with open_artifact(scene_path) as f:
        clip, names = read(f, "motion/clip", np.int64), [str(n) for n in f["motion/clip_names"].asstr()[()]]
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
    with open_artifact(scene_path) as f:
        if "torso_transforms" not in f:
            raise PipelineError(f"{scene_path}: --frame torso needs dataset 'torso_transforms' (F, 4, 4), "
                                f"world-from-torso per frame; this scene has no torso (use --frame world)")
        transforms = read(f, "torso_transforms", np.float64)
    if transforms.shape != (n_frames, 4, 4):
        raise PipelineError(f"{scene_path}: 'torso_transforms' must be ({n_frames}, 4, 4), got {transforms.shape}")
    rotation = transforms[:, :3, :3]
    if not np.allclose(rotation @ rotation.transpose(0, 2, 1), np.eye(3), atol=1e-5):
        raise PipelineError(f"{scene_path}: 'torso_transforms' rotations are not orthonormal")
    return transforms


def build_dataset(low_path: str, high_path: str, subdiv_path: str, frame: str,
                  scene_path: str | None) -> dict[str, np.ndarray]:
    """Arrays of the learning problem; raises PipelineError naming the file that does not fit the others."""
    with open_artifact(low_path) as f:
        low, low_faces = read(f, "positions", np.float64), read(f, "faces", np.int32)
    with open_artifact(high_path) as f:
        high, high_faces = read(f, "positions", np.float64), read(f, "faces", np.int32)
    with open_artifact(subdiv_path) as f:
        subdivision = read_csr(f, "S")
        rest, subdiv_faces = read(f, "vertices", np.float64), read(f, "faces", np.int32)
    if subdivision.shape != (high.shape[1], low.shape[1]):
        raise PipelineError(f"{subdiv_path}: S is {subdivision.shape} but {high_path} has {high.shape[1]} and "
                            f"{low_path} {low.shape[1]} vertices")
    if high_faces.shape != subdiv_faces.shape or not np.array_equal(high_faces, subdiv_faces):
        raise PipelineError(f"{high_path}: its faces differ from {subdiv_path}'s: not the same high-res mesh")
    if len(low) != len(high):
        raise PipelineError(f"{high_path}: {len(high)} frames but {low_path} has {len(low)}")
    transforms = _torso_transforms(scene_path, len(low)) if frame == "torso" else None
    if transforms is not None:
        low = apply_rigid_inverse(transforms[:, None], low)
        high = apply_rigid_inverse(transforms[:, None], high)
    subdivided = np.stack([subdivision @ x for x in low])
    return {"input": subdivided.astype(np.float32), "target": (high - subdivided).astype(np.float32),
            "faces": subdiv_faces, "rest_vertices": rest, "low/positions": low.astype(np.float32),
            "low/faces": low_faces}


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
    args = parser.parse_args(argv)
    if not 0 < args.test_fraction < 1:
        raise PipelineError(f"--test-fraction must lie in (0, 1), got {args.test_fraction}")
    arrays = build_dataset(args.sim_low, args.sim_high, args.subdiv, args.frame, args.scene)
    n_frames = len(arrays["input"])
    test_clips = [c.strip() for c in (args.test_clips or "").split(",") if c.strip()]
    held = held_out_frames(args.scene, n_frames, test_clips) if test_clips else np.zeros(0, np.int64)
    train, test, held = split_dataset(n_frames, args.test_fraction, args.seed, held)
    config = {name: getattr(args, name) for name in ("sim_low", "sim_high", "subdiv", "frame", "scene",
                                                    "test_fraction", "test_clips", "seed")}
    with atomic_h5(args.out, "dataset", config) as f:
        for name, data in arrays.items():
            f.create_dataset(name, data=data)
        f["predictor"] = f["input"]          # a hard link: Table 2's predictor is the input itself
        f.create_dataset("split/train", data=train.astype(np.int64))
        f.create_dataset("split/test", data=test.astype(np.int64))
        f.create_dataset("split/held_out", data=held)
        f["split"].attrs["meaning"] = ("train: frames trained on; test: a seeded random share of the other frames of "
                                       "the same motions; held_out: every frame of the clips named in attr "
                                       "held_out_clips (unseen motion; may be empty)")
        f["split"].attrs["held_out_clips"] = ",".join(test_clips)
        f.attrs.update(problem="cloth upsampling (paper Table 2)", frame=args.frame, n_frames=len(arrays["input"]),
                       n_vertices=arrays["input"].shape[1], split_seed=args.seed, test_fraction=args.test_fraction)
        f["input"].attrs["meaning"] = "Loop-subdivided low-res positions S x_low, per frame (F, V_high, 3)"
        f["target"].attrs["meaning"] = "displacement x_high - S x_low, per frame (F, V_high, 3)"
    if not args.quiet:
        print(f"dataset: {n_frames} frames ({len(train)} train, {len(test)} test, {len(held)} held out) of "
              f"{arrays['input'].shape[1]} vertices, {args.frame} frame -> {args.out}")


if __name__ == "__main__":
    cli.run(main)
