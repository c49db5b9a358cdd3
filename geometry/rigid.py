"""Rigid transforms as 4 x 4 matrices [R t; 0 1], applied to points: the one helper that pins, torso frames and
rods share. Leading dimensions broadcast, so a (F, G, 4, 4) stack of per-frame, per-group transforms applies to
(N, 3) points after picking each point's group: `apply_rigid(transforms[:, group], points)` is (F, N, 3)."""
from __future__ import annotations

import numpy as np


def apply_rigid(transforms: np.ndarray, points: np.ndarray) -> np.ndarray:
    """R p + t for transforms (..., 4, 4) and points (..., 3), broadcasting the leading dimensions."""
    return np.einsum("...ij,...j->...i", transforms[..., :3, :3], points) + transforms[..., :3, 3]


def apply_rigid_inverse(transforms: np.ndarray, points: np.ndarray) -> np.ndarray:
    """R^T (p - t): world points expressed in the frame whose world-from-frame transforms (..., 4, 4) are given."""
    return np.einsum("...ji,...j->...i", transforms[..., :3, :3], points - transforms[..., :3, 3])
