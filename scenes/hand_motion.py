"""Joint-angle trajectories of the hand (the 18 angles of scenes.hand_skeleton), frame by frame.

- `random_trajectory`: seeded keyframes drawn uniformly within each angle's limits at random intervals, joined
  by smootherstep (C2) blends. A blend never leaves the interval between its two keyframes, so every frame is
  within the limits without clamping; the speeds stay bounded by the keyframe spacing. It starts at rest and
  blends into its first keyframe, as a simulation from rest must.
- `fist_trajectory`: the held-out motion, of a kind never trained on: from the open hand, the fingers close one
  after the other (little first, index last, each overlapping the next), the thumb folds over them, the fist
  holds, and the hand opens again all at once.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from scenes.hand_skeleton import ANGLE_LIMITS, ANGLE_NAMES, fist_angles
from scenes.sequences import TRAIN, parse_sequence_name


def _smootherstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (t * (6.0 * t - 15.0) + 10.0)


def random_trajectory(frames: int, fps: float, seed: int, min_interval: float = 0.4,
                      max_interval: float = 1.2) -> np.ndarray:
    """(frames, 18) angles; each angle's keyframes at its own random times (min_interval..max_interval seconds
    apart), so the fingers do not move in lockstep."""
    if frames < 1 or not fps > 0 or not 0 < min_interval <= max_interval:
        raise ValueError(f"need frames >= 1, fps > 0 and 0 < min_interval <= max_interval; got {frames}, {fps}, "
                         f"{min_interval}, {max_interval}")
    rng = np.random.default_rng(seed)
    time = np.arange(frames) / fps
    out = np.empty((frames, len(ANGLE_NAMES)))
    for k, (lo, hi) in enumerate(ANGLE_LIMITS):
        gaps = rng.uniform(min_interval, max_interval, int(time[-1] / min_interval) + 2)
        keys_t = np.concatenate([[0.0], np.cumsum(gaps)])
        keys = np.concatenate([[0.0], rng.uniform(lo, hi, len(gaps))])       # frame 0: rest
        i = np.searchsorted(keys_t, time, side="right") - 1
        s = _smootherstep((time - keys_t[i]) / (keys_t[i + 1] - keys_t[i]))
        out[:, k] = keys[i] + s * (keys[i + 1] - keys[i])
    return out


# The order the fist closes in, and how far each step's start lags the last (a share of one finger's closing).
FIST_ORDER = ("little", "ring", "middle", "index", "thumb")
FIST_LAG = 0.6


def fist_trajectory(frames: int) -> np.ndarray:
    """(frames, 18) angles: rest, closing finger by finger (70% of the frames), held, then opening (the last 20%)."""
    if frames < 10:
        raise ValueError(f"a fist needs at least 10 frames, got {frames}")
    closed = fist_angles(1.0)
    t = np.arange(frames) / (frames - 1)
    closing_end, opening_start = 0.7, 0.8
    one = closing_end / (1 + FIST_LAG * (len(FIST_ORDER) - 1))     # how long one finger takes to close
    opening = 1.0 - _smootherstep((t - opening_start) / (1.0 - opening_start))
    out = np.zeros((frames, len(ANGLE_NAMES)))
    for step, finger in enumerate(FIST_ORDER):
        start = step * FIST_LAG * one
        closure = _smootherstep((t - start) / one) * opening
        for k, name in enumerate(ANGLE_NAMES):
            if name.startswith(finger):
                out[:, k] = closure * closed[k]
    return out


# The held-out motions a config may name (drivers.hand.test_motions), each of `frames` frames.
HELD_OUT_MOTIONS = {"fist": fist_trajectory}


def sequence_angles(name: str, frames: int, fps: float, drive: Mapping) -> np.ndarray:
    """(frames, 18) the angles sequence `name` plays (scenes.sequences): training sequence k the random trajectory
    of seed drive["seed"] + k, held-out sequence k the motion drive["test_motions"][k]. ValueError for a name
    the drive has no motion for."""
    role, index = parse_sequence_name(name)
    if role == TRAIN:
        return random_trajectory(frames, fps, drive["seed"] + index, drive["min_interval"], drive["max_interval"])
    motions = drive["test_motions"]
    if index >= len(motions) or motions[index] not in HELD_OUT_MOTIONS:
        raise ValueError(f"no held-out hand motion for sequence '{name}' (test_motions: {motions})")
    return HELD_OUT_MOTIONS[motions[index]](frames)
