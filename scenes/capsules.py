"""The mannequin's collision shape: one tapered capsule per body part, placed in world space for part transforms
(from `scenes.kinematics`), with end-point velocities, signed distances and clearances between parts.

A tapered capsule is the convex hull of a sphere of radius `radius_a` at `capsule_a` and one of radius `radius_b`
at `capsule_b` (end points in the part's frame, see `scenes.skeleton.Skeleton`).
"""
from __future__ import annotations

import numpy as np

from geometry.rotations import quat_rotate
from scenes.kinematics import rest_transforms
from scenes.skeleton import Skeleton


def capsules_world(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Capsule end points a, b (..., P, 3) in world space and their radii (..., P) for part transforms."""
    rotation, translation = transforms
    a = quat_rotate(rotation, skel.capsule_a) + translation
    b = quat_rotate(rotation, skel.capsule_b) + translation
    batch = a.shape[:-1]
    return a, b, np.broadcast_to(skel.radius_a, batch).copy(), np.broadcast_to(skel.radius_b, batch).copy()


def capsule_velocities(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray],
                       velocities: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """World velocities (..., P, 3) of the capsule end points a and b, from part (linear, angular) velocities."""
    rotation, _ = transforms
    linear, angular = velocities
    va = linear + np.cross(angular, quat_rotate(rotation, skel.capsule_a))
    vb = linear + np.cross(angular, quat_rotate(rotation, skel.capsule_b))
    return va, vb


def capsule_signed_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray, radius_a: np.ndarray,
                            radius_b: np.ndarray) -> np.ndarray:
    """Signed distance (N, P) from points (N, 3) to P tapered capsules (negative inside).

    In the plane through the axis, the surface is two circles joined by their common tangent line, which touches
    them where the outward normal leans by phi (sin phi = (r_a - r_b) / length) toward b. Points whose
    projection along that line falls before the tangent point on a (or after the one on b) are nearest the
    sphere; the others are nearest the line.
    """
    points = np.asarray(points, dtype=np.float64)
    axis = b - a
    length = np.linalg.norm(axis, axis=-1)
    unit = axis / length[..., None]
    rel = points[:, None, :] - a[None]
    s = np.einsum("npk,pk->np", rel, unit)
    q = np.linalg.norm(rel - s[..., None] * unit[None], axis=-1)
    sin_phi = (radius_a - radius_b) / length
    cos_phi = np.sqrt(1.0 - sin_phi ** 2)
    along = s * cos_phi - q * sin_phi
    side = s * sin_phi + q * cos_phi - radius_a
    to_a = np.sqrt(s * s + q * q) - radius_a
    to_b = np.sqrt((s - length) ** 2 + q * q) - radius_b
    return np.where(along <= 0.0, to_a, np.where(along >= length * cos_phi, to_b, side))


def body_signed_distance(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray], points: np.ndarray,
                         parts: np.ndarray | None = None) -> np.ndarray:
    """Signed distance (N,) from points to the union of the body's capsules (or of the listed part indices)."""
    a, b, ra, rb = capsules_world(skel, transforms)
    if parts is not None:
        a, b, ra, rb = a[parts], b[parts], ra[parts], rb[parts]
    return capsule_signed_distance(points, a, b, ra, rb).min(axis=1)


def segment_closest_parameters(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray,
                               q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameters s, t in [0, 1] of the closest points p0 + s (p1 - p0), q0 + t (q1 - q0) of segment pairs."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...k,...k->...", d1, d1)
    e = np.einsum("...k,...k->...", d2, d2)
    b = np.einsum("...k,...k->...", d1, d2)
    c = np.einsum("...k,...k->...", d1, r)
    f = np.einsum("...k,...k->...", d2, r)
    denom = a * e - b * b
    parallel = denom <= 1e-12 * a * e
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0))
    t = (b * s + f) / e
    # Where t leaves [0, 1], clamp it and recompute the best s for that end.
    t_clamped = np.clip(t, 0.0, 1.0)
    s = np.where(t != t_clamped, np.clip((b * t_clamped - c) / a, 0.0, 1.0), s)
    return s, t_clamped


def capsule_pair_clearance(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray],
                           pairs: np.ndarray) -> np.ndarray:
    """Approximate gap (..., K) between the capsules of part pairs (K, 2); negative where they interpenetrate.

    The gap is the distance between the closest points of the two axis segments minus the radii interpolated
    there: exact for untapered capsules, within a fraction of the taper otherwise.
    """
    a, b, ra, rb = capsules_world(skel, transforms)
    i, j = pairs[:, 0], pairs[:, 1]
    s, t = segment_closest_parameters(a[..., i, :], b[..., i, :], a[..., j, :], b[..., j, :])
    p = a[..., i, :] + s[..., None] * (b[..., i, :] - a[..., i, :])
    q = a[..., j, :] + t[..., None] * (b[..., j, :] - a[..., j, :])
    radius_i = ra[..., i] + s * (rb[..., i] - ra[..., i])
    radius_j = ra[..., j] + t * (rb[..., j] - ra[..., j])
    return np.linalg.norm(p - q, axis=-1) - radius_i - radius_j


def self_collision_pairs(skel: Skeleton, margin: float = 0.02) -> np.ndarray:
    """Part pairs (K, 2) whose capsules are apart by more than `margin` (scaled with height) in the rest pose:
    the pairs that must not touch in a plausible pose. Neighbours that overlap at their joints are left out."""
    n = skel.n_parts
    i, j = np.triu_indices(n, k=1)
    pairs = np.stack([i, j], axis=1)
    gap = capsule_pair_clearance(skel, rest_transforms(skel), pairs)
    return pairs[gap > margin * skel.height / 1.7]


def limbs_through_each_other(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray], pairs: np.ndarray,
                             depth: float = 1.0) -> tuple[float, int, tuple[str, str]] | None:
    """Where two capsules of part pairs (K, 2) pass through each other over frames of part transforms ((F, P, 4),
    (F, P, 3)): interpenetrate deeper than `depth` times the thinner one's mean radius (one limb's axis inside the
    other). The worst such (overlap in m, frame, the parts' names), or None. Touching, and sinking in a little as
    soft limbs do, is not passing through."""
    gap = capsule_pair_clearance(skel, transforms, pairs)
    radius = (skel.radius_a + skel.radius_b) / 2
    through = -gap / np.minimum(radius[pairs[:, 0]], radius[pairs[:, 1]])
    frame, k = np.unravel_index(int(np.argmax(through)), through.shape)
    if through[frame, k] <= depth:
        return None
    return -float(gap[frame, k]), int(frame), (skel.names[pairs[k, 0]], skel.names[pairs[k, 1]])
