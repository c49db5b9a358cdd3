"""The procedural mannequin: a skeleton of capsule body parts, forward kinematics and collision shapes as arrays.

Conventions: y is up, the body faces +z, its left side is +x and the feet rest on y = 0 in the rest pose.
Quaternions are (x, y, z, w). Every body part has a frame whose origin is its joint with the parent part (the
pelvis origin is the root). In the rest pose every joint rotation is the identity, so a part's world rotation is
the product of the fixed `frame_rotations` down its chain (only the upper arms have one: they hang 45° out from
the body, an A-pose that leaves room for sleeves). Joint angles are radians about the x, y, z axes of the joint
frame and compose as R = Rz(a_z) Rx(a_x) Ry(a_y): twist about the bone (y) first, then flexion (x), then
abduction (z). For a limb hanging down a negative x angle swings it forward (+z); for the spine a positive x
angle bends it forward; a positive z angle moves a left limb outward (+x). Capsules may be tapered: the surface
is the convex hull of a sphere of radius `radius_a` at `capsule_a` and one of radius `radius_b` at `capsule_b`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# ---------------------------------------------------------------------------------------------------------------
# Quaternions (x, y, z, w), broadcasting over leading axes.


def quat_multiply(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product q r (apply r first, then q)."""
    x1, y1, z1, w1 = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    x2, y2, z2, w2 = np.moveaxis(np.asarray(r, dtype=np.float64), -1, 0)
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                     w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    return np.asarray(q, dtype=np.float64) * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation by `angle` (...) radians about the unit `axis` (3,) or (..., 3)."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)
    return np.concatenate([np.asarray(axis, dtype=np.float64) * np.sin(half)[..., None],
                           np.cos(half)[..., None]], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """The representative with w >= 0 of each rotation (q and -q are the same rotation)."""
    q = np.asarray(q, dtype=np.float64)
    return np.where(q[..., 3:] < 0.0, -q, q)


_X, _Y, _Z = np.eye(3)


def joint_quaternions(angles: np.ndarray) -> np.ndarray:
    """Joint rotations (..., 4) from joint angles (..., 3): R = Rz(a_z) Rx(a_x) Ry(a_y)."""
    angles = np.asarray(angles, dtype=np.float64)
    return quat_multiply(quat_from_axis_angle(_Z, angles[..., 2]),
                         quat_multiply(quat_from_axis_angle(_X, angles[..., 0]),
                                       quat_from_axis_angle(_Y, angles[..., 1])))


def joint_angular_velocity(angles: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Angular velocity (..., 3) of R = Rz Rx Ry for angle rates (..., 3), in the frame the joint rotates in."""
    angles = np.asarray(angles, dtype=np.float64)
    rates = np.asarray(rates, dtype=np.float64)
    qz = quat_from_axis_angle(_Z, angles[..., 2])
    qzx = quat_multiply(qz, quat_from_axis_angle(_X, angles[..., 0]))
    return (rates[..., 2:3] * _Z + rates[..., 0:1] * quat_rotate(qz, _X)
            + rates[..., 1:2] * quat_rotate(qzx, _Y))


# ---------------------------------------------------------------------------------------------------------------
# Skeleton


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A tree of P rigid body parts, each carrying one (possibly tapered) capsule. Parents precede children.

    joint_offsets[p] is the joint of part p in its parent's frame; for the root it is the rest root position in
    world space. frame_rotations[p] is the rest rotation of part p's frame relative to its parent's frame.
    Capsule end points are in the part's own frame. Joint limits bound the joint angles (radians, x/y/z as in the
    module docstring); the rest pose (all zero) lies within them.
    """
    names: tuple[str, ...]
    parents: np.ndarray          # (P,) int64, -1 for the root
    joint_offsets: np.ndarray    # (P, 3)
    frame_rotations: np.ndarray  # (P, 4)
    capsule_a: np.ndarray        # (P, 3)
    capsule_b: np.ndarray        # (P, 3)
    radius_a: np.ndarray         # (P,)
    radius_b: np.ndarray         # (P,)
    joint_lower: np.ndarray      # (P, 3) radians
    joint_upper: np.ndarray      # (P, 3) radians
    height: float

    def __post_init__(self):
        p = len(self.names)
        shapes = {"parents": (p,), "joint_offsets": (p, 3), "frame_rotations": (p, 4), "capsule_a": (p, 3),
                  "capsule_b": (p, 3), "radius_a": (p,), "radius_b": (p,), "joint_lower": (p, 3),
                  "joint_upper": (p, 3)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"skeleton field '{name}' must have shape {shape}, "
                                 f"got {np.shape(getattr(self, name))}")
        if self.parents[0] != -1 or any(not 0 <= self.parents[i] < i for i in range(1, p)):
            raise ValueError("skeleton parents must list the root first (-1) and every parent before its children")
        if (self.radius_a <= 0).any() or (self.radius_b <= 0).any():
            raise ValueError("capsule radii must be positive")
        length = np.linalg.norm(self.capsule_b - self.capsule_a, axis=1)
        if (length <= np.abs(self.radius_a - self.radius_b)).any():
            raise ValueError("a capsule's segment must be longer than the difference of its end radii")
        if ((self.joint_lower > 0) | (self.joint_upper < 0)).any():
            raise ValueError("joint limits must contain the rest pose (zero angles)")

    @property
    def n_parts(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the part called `name` (ValueError listing the names otherwise)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no body part '{name}'; parts are {', '.join(self.names)}") from None


# Part: parent, joint offset, frame rotation about z (deg), capsule a, capsule b, radius a, radius b, and joint
# limits (deg) (x_lo, x_hi, y_lo, y_hi, z_lo, z_hi) for the left side or the midline. Lengths are for a 1.7 tall
# body; right parts mirror their left twins (x offsets and y/z angles change sign).
_TEMPLATE = {
    "pelvis": (None, (0, 0.95, 0), 0, (-0.08, 0, 0), (0.08, 0, 0), 0.10, 0.10, (-30, 30, -90, 90, -20, 20)),
    "spine": ("pelvis", (0, 0.07, 0), 0, (-0.05, 0.08, 0), (0.05, 0.08, 0), 0.095, 0.095, (-20, 45, -35, 35, -25, 25)),
    "chest": ("spine", (0, 0.17, 0), 0, (-0.07, 0.11, 0), (0.07, 0.11, 0), 0.12, 0.12, (-15, 30, -30, 30, -20, 20)),
    "head": ("chest", (0, 0.24, 0), 0, (0, 0, 0), (0, 0.175, 0.01), 0.05, 0.095, (-40, 50, -70, 70, -35, 35)),
    "upper_arm_l": ("chest", (0.18, 0.20, 0), 45, (0, 0, 0), (0, -0.29, 0), 0.05, 0.042, (-150, 50, -70, 70, -30, 90)),
    "lower_arm_l": ("upper_arm_l", (0, -0.29, 0), 0, (0, 0, 0), (0, -0.25, 0), 0.04, 0.032, (-145, 0, -60, 60, 0, 0)),
    "hand_l": ("lower_arm_l", (0, -0.25, 0), 0, (0, -0.04, 0), (0, -0.14, 0), 0.035, 0.03, (-70, 70, 0, 0, -20, 30)),
    "thigh_l": ("pelvis", (0.10, -0.05, 0), 0, (0, 0, 0), (0, -0.41, 0), 0.075, 0.052, (-120, 30, -40, 40, -20, 45)),
    "shin_l": ("thigh_l", (0, -0.41, 0), 0, (0, 0, 0), (0, -0.39, 0), 0.05, 0.04, (0, 140, 0, 0, 0, 0)),
    "foot_l": ("shin_l", (0, -0.40, 0), 0, (0, -0.05, -0.03), (0, -0.06, 0.15), 0.04, 0.03,
               (-25, 45, -20, 20, -15, 15)),
}
_PART_ORDER = ("pelvis", "spine", "chest", "head", "upper_arm_l", "lower_arm_l", "hand_l", "upper_arm_r",
               "lower_arm_r", "hand_r", "thigh_l", "shin_l", "foot_l", "thigh_r", "shin_r", "foot_r")
TORSO = "pelvis"  # the frame pose vectors and torso-relative data are expressed in


def mirror_name(name: str) -> str:
    """The left/right twin of a part name (midline parts map to themselves)."""
    if name.endswith("_l"):
        return name[:-2] + "_r"
    if name.endswith("_r"):
        return name[:-2] + "_l"
    return name


def default_skeleton(height: float = 1.7) -> Skeleton:
    """The 16-part mannequin of the given standing height (rest pose: A-pose, feet on y = 0, facing +z)."""
    if not height > 0:
        raise ValueError(f"height must be positive, got {height}")
    scale = height / 1.7
    fields = {k: [] for k in ("parents", "offsets", "frames", "a", "b", "ra", "rb", "lo", "hi")}
    flip = np.array([-1.0, 1.0, 1.0])
    for name in _PART_ORDER:
        mirrored = name not in _TEMPLATE
        parent, offset, frame_deg, a, b, ra, rb, limits = _TEMPLATE[mirror_name(name) if mirrored else name]
        lim = np.radians(np.reshape(limits, (3, 2)))
        offset, a, b = (np.array(v, dtype=np.float64) for v in (offset, a, b))
        if mirrored:
            parent = mirror_name(parent)
            offset, a, b = offset * flip, a * flip, b * flip
            frame_deg = -frame_deg
            lim[1:] = -lim[1:, ::-1]
        fields["parents"].append(-1 if parent is None else _PART_ORDER.index(parent))
        fields["offsets"].append(offset)
        fields["frames"].append(quat_from_axis_angle(_Z, np.radians(frame_deg)))
        fields["a"].append(a)
        fields["b"].append(b)
        fields["ra"].append(ra)
        fields["rb"].append(rb)
        fields["lo"].append(lim[:, 0])
        fields["hi"].append(lim[:, 1])
    offsets = np.array(fields["offsets"]) * scale
    return Skeleton(names=_PART_ORDER, parents=np.array(fields["parents"], dtype=np.int64),
                    joint_offsets=offsets, frame_rotations=np.array(fields["frames"]),
                    capsule_a=np.array(fields["a"]) * scale, capsule_b=np.array(fields["b"]) * scale,
                    radius_a=np.array(fields["ra"]) * scale, radius_b=np.array(fields["rb"]) * scale,
                    joint_lower=np.array(fields["lo"]), joint_upper=np.array(fields["hi"]), height=float(height))


# ---------------------------------------------------------------------------------------------------------------
# Kinematics


def forward_kinematics(skel: Skeleton, root_position: np.ndarray,
                       joint_rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (..., P, 4) and translations (..., P, 3) of every part frame.

    root_position (..., 3) is the world position of the pelvis origin; joint_rotations (..., P, 4) the local
    joint rotations (the root's is its world orientation). Leading axes (e.g. frames) broadcast.
    """
    joint_rotations = np.asarray(joint_rotations, dtype=np.float64)
    root_position = np.asarray(root_position, dtype=np.float64)
    if joint_rotations.shape[-2:] != (skel.n_parts, 4):
        raise ValueError(f"joint_rotations must have shape (..., {skel.n_parts}, 4), got {joint_rotations.shape}")
    batch = np.broadcast_shapes(joint_rotations.shape[:-2], root_position.shape[:-1])
    rotation = np.empty(batch + (skel.n_parts, 4))
    translation = np.empty(batch + (skel.n_parts, 3))
    for p, parent in enumerate(skel.parents):
        local = quat_multiply(skel.frame_rotations[p], joint_rotations[..., p, :])
        if parent < 0:
            rotation[..., p, :] = local
            translation[..., p, :] = root_position
        else:
            rotation[..., p, :] = quat_multiply(rotation[..., parent, :], local)
            translation[..., p, :] = translation[..., parent, :] + quat_rotate(rotation[..., parent, :],
                                                                               skel.joint_offsets[p])
    rotation /= np.linalg.norm(rotation, axis=-1, keepdims=True)
    return rotation, translation


def rest_transforms(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (P, 4) and translations (P, 3) of the rest pose."""
    identity = np.tile([0.0, 0.0, 0.0, 1.0], (skel.n_parts, 1))
    return forward_kinematics(skel, skel.joint_offsets[0], identity)


def part_velocities(skel: Skeleton, part_rotation: np.ndarray, joint_omega: np.ndarray,
                    root_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World linear velocity of each part origin and world angular velocity of each part, (..., P, 3) each.

    part_rotation (..., P, 4) comes from `forward_kinematics`; joint_omega (..., P, 3) is each joint's angular
    velocity in the frame it rotates in (see `joint_angular_velocity`); root_velocity (..., 3) that of the root.
    """
    part_rotation = np.asarray(part_rotation, dtype=np.float64)
    joint_omega = np.asarray(joint_omega, dtype=np.float64)
    shape = part_rotation.shape[:-1] + (3,)
    linear, angular = np.empty(shape), np.empty(shape)
    for p, parent in enumerate(skel.parents):
        if parent < 0:
            angular[..., p, :] = quat_rotate(skel.frame_rotations[p], joint_omega[..., p, :])
            linear[..., p, :] = root_velocity
        else:
            base = quat_multiply(part_rotation[..., parent, :], skel.frame_rotations[p])
            angular[..., p, :] = angular[..., parent, :] + quat_rotate(base, joint_omega[..., p, :])
            lever = quat_rotate(part_rotation[..., parent, :], skel.joint_offsets[p])
            linear[..., p, :] = linear[..., parent, :] + np.cross(angular[..., parent, :], lever)
    return linear, angular


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


# ---------------------------------------------------------------------------------------------------------------
# Distances


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


# ---------------------------------------------------------------------------------------------------------------
# Render / test mesh


def body_mesh(skel: Skeleton, transforms: tuple[np.ndarray, np.ndarray],
              segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the body for one pose: one closed, outward-oriented surface per capsule (they overlap
    where parts meet; each is watertight). `segments` vertices around each ring; each cap has segments // 4
    rings. Returns vertices (P * (2 + 2 * k * segments), 3) and faces, part p's vertices contiguous."""
    if segments < 3:
        raise ValueError(f"segments must be at least 3, got {segments}")
    a, b, ra, rb = capsules_world(skel, transforms)
    if a.ndim != 2:
        raise ValueError("body_mesh takes the transforms of a single pose")
    rings = max(2, segments // 4)
    axis = b - a
    length = np.linalg.norm(axis, axis=1)
    unit = axis / length[:, None]
    e1 = np.cross(unit, np.where(np.abs(unit[:, 1:2]) < 0.9, _Y, _X))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(unit, e1)
    # Normal direction angle psi from -axis: sphere a up to the tangent ring psi_c = pi/2 + phi, then sphere b.
    psi_c = 0.5 * np.pi + np.arcsin((ra - rb) / length)
    fa = np.arange(1, rings + 1) / rings
    fb = np.arange(rings) / rings
    psi = np.concatenate([np.outer(psi_c, fa), psi_c[:, None] + np.outer(np.pi - psi_c, fb)], axis=1)  # (P, 2k)
    center = np.concatenate([np.repeat(a[:, None], rings, 1), np.repeat(b[:, None], rings, 1)], axis=1)
    radius = np.concatenate([np.repeat(ra[:, None], rings, 1), np.repeat(rb[:, None], rings, 1)], axis=1)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    radial = (np.cos(phi)[None, :, None] * e1[:, None, :] + np.sin(phi)[None, :, None] * e2[:, None, :])
    normal = (-np.cos(psi)[:, :, None, None] * unit[:, None, None, :]
              + np.sin(psi)[:, :, None, None] * radial[:, None, :, :])                         # (P, 2k, S, 3)
    ring_points = center[:, :, None, :] + radius[:, :, None, None] * normal
    poles = np.stack([a - ra[:, None] * unit, b + rb[:, None] * unit], axis=1)                  # (P, 2, 3)
    per_part = 2 + 2 * rings * segments
    vertices = np.concatenate([poles[:, :1], ring_points.reshape(len(a), -1, 3), poles[:, 1:]], axis=1)
    faces = _closed_tube_faces(2 * rings, segments)
    all_faces = faces[None] + per_part * np.arange(len(a))[:, None, None]
    return vertices.reshape(-1, 3), all_faces.reshape(-1, 3).astype(np.int64)


def _closed_tube_faces(n_rings: int, segments: int) -> np.ndarray:
    """Faces of a pole (vertex 0), n_rings rings of `segments` vertices running counter-clockwise about the
    axis, and a second pole (last vertex), outward when the rings advance along the axis."""
    ring = 1 + np.arange(n_rings)[:, None] * segments + np.arange(segments)[None, :]
    nxt = np.roll(ring, -1, axis=1)
    last = 1 + n_rings * segments
    south = np.stack([np.zeros(segments, dtype=np.int64), nxt[0], ring[0]], axis=1)
    north = np.stack([ring[-1], nxt[-1], np.full(segments, last)], axis=1)
    r00, r01, r10, r11 = ring[:-1], nxt[:-1], ring[1:], nxt[1:]
    bands = np.concatenate([np.stack([r00, r01, r11], -1).reshape(-1, 3), np.stack([r00, r11, r10], -1).reshape(-1, 3)])
    return np.concatenate([south, bands, north])


def skeleton_from_h5(group) -> Skeleton:
    """The skeleton stored in a scene.h5 `body` group (see docs/artifacts.md)."""
    fields = ("joint_offsets", "frame_rotations", "capsule_a", "capsule_b", "radius_a", "radius_b", "joint_lower",
              "joint_upper")
    return Skeleton(names=tuple(n.decode() for n in group["names"][()]), parents=group["parents"][()].astype(np.int64),
                    **{name: np.asarray(group[name][()], dtype=np.float64) for name in fields},
                    height=float(group.attrs["height"]))
