"""The mannequin's skeleton: a tree of rigid body parts, their joint frames and limits, and the capsule each part
carries (its collision and render shape, placed in world space by `scenes.capsules`).

Conventions: y is up, the body faces +z, its left side is +x and the feet rest on y = 0 in the rest pose.
Quaternions are (x, y, z, w). Every body part has a frame whose origin is its joint with the parent part (the
pelvis origin is the root). In the rest pose every joint rotation is the identity, so a part's world rotation is
the product of the fixed `frame_rotations` down its chain (only the upper arms have one: they hang 45° out from
the body, an A-pose that leaves room for sleeves). Joint angles are radians about the x, y, z axes of the joint
frame and compose as R = Rz(a_z) Rx(a_x) Ry(a_y) (`scenes.kinematics.joint_quaternions`): twist about the bone
(y) first, then flexion (x), then abduction (z). For a limb hanging down a negative x angle swings it forward
(+z); for the spine a positive x angle bends it forward; a positive z angle moves a left limb outward (+x).
Capsules may be tapered: the surface is the convex hull of a sphere of radius `radius_a` at `capsule_a` and one
of radius `radius_b` at `capsule_b`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.rotations import UNIT_Z, quat_from_axis_angle


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
        fields["frames"].append(quat_from_axis_angle(UNIT_Z, np.radians(frame_deg)))
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
