"""The procedural hand's bones: a `Skeleton` of 17 parts (a forearm stump, the palm, the thumb's metacarpal and
two phalanges, three phalanges for each finger), the 18 joint angles that pose it and their anatomical limits.

Conventions (the hand's own frame, metres): the fingers point along +y, the palm faces +z, the thumb is on the +x
side (a right hand seen from its palm), the wrist joint is at the origin. Each part's frame has its bone along
its +y axis, so a positive x angle flexes it towards the palm (+z) and a z angle spreads it sideways
(`scenes.kinematics`: R = Rz Rx Ry).

The 18 angles (`ANGLE_NAMES`): wrist flexion and deviation; for each finger the metacarpophalangeal (MCP)
flexion and abduction and the proximal interphalangeal (PIP) flexion, the distal (DIP) following as 2/3 of the
PIP (the tendon coupling of Rijpkema and Girard 1991, which no one can bend apart at will); for the thumb its base
joint (carpometacarpal, CMC) flexion and abduction, MCP and interphalangeal (IP) flexion. Limits after Hume et al.
1990 and Kapandji, narrowed where this hand's flesh, which has no self-contact, would be crushed flat between two
bones and invert its tets: PIP flexion to 90 degrees (anatomically ~105; at 100 the palmar flesh of a 6 mm mesh
inverts), the thumb's CMC extension and adduction to 5 degrees (beyond, its metacarpal presses into the index's).
"""
from __future__ import annotations

import numpy as np

from geometry.rotations import UNIT_Y, UNIT_Z, quat_from_axis_angle, quat_multiply
from scenes.kinematics import forward_kinematics, joint_quaternions
from scenes.skeleton import Skeleton

FINGERS = ("index", "middle", "ring", "little")
DIP_COUPLING = 2.0 / 3.0

# Finger: MCP joint in the palm frame, splay about z (deg, + towards the little finger), phalanx lengths, radii
# at the MCP, PIP, DIP and the tip.
_FINGER_SHAPE = {
    "index": ((0.027, 0.086, 0.0), -9.0, (0.040, 0.024, 0.019), (0.0098, 0.0088, 0.0080, 0.0072)),
    "middle": ((0.004, 0.091, 0.0), 0.0, (0.045, 0.028, 0.021), (0.0100, 0.0090, 0.0082, 0.0073)),
    "ring": ((-0.018, 0.086, 0.0), 9.0, (0.042, 0.026, 0.020), (0.0094, 0.0085, 0.0078, 0.0070)),
    "little": ((-0.037, 0.076, 0.0), 19.0, (0.033, 0.019, 0.018), (0.0085, 0.0077, 0.0070, 0.0063)),
}
# The thumb's own twist about its bone (deg): its nail faces sideways, so it flexes across the palm, not into it.
THUMB_TWIST = 70.0
# The thumb: CMC joint in the palm frame, its rest direction (rotation about z, then its twist about y, deg),
# metacarpal and phalanx lengths and radii.
_THUMB = ((0.020, 0.012, 0.010), -40.0, THUMB_TWIST, (0.044, 0.032, 0.027), (0.0135, 0.0108, 0.0098, 0.0088, 0.0078))

# (name, part, axis, lower, upper) in degrees; the DIP joints are not here (they follow their PIP).
_ANGLES = [("wrist_flexion", "palm", 0, -60.0, 70.0), ("wrist_deviation", "palm", 2, -25.0, 15.0)]
for _f in FINGERS:
    _ANGLES += [(f"{_f}_mcp_flexion", f"{_f}_1", 0, -20.0, 90.0), (f"{_f}_mcp_abduction", f"{_f}_1", 2, -10.0, 10.0),
                (f"{_f}_pip_flexion", f"{_f}_2", 0, 0.0, 90.0)]
_ANGLES += [("thumb_cmc_flexion", "thumb_0", 0, -5.0, 45.0), ("thumb_cmc_abduction", "thumb_0", 2, -5.0, 25.0),
            ("thumb_mcp_flexion", "thumb_1", 0, -10.0, 60.0), ("thumb_ip_flexion", "thumb_2", 0, -10.0, 80.0)]
ANGLE_NAMES = tuple(a[0] for a in _ANGLES)
ANGLE_LIMITS = np.radians(np.array([(a[3], a[4]) for a in _ANGLES]))     # (18, 2) radians


def _part(fields: dict, name: str, parent: str | None, offset, frame, length: float, r0: float, r1: float,
          limits=None) -> None:
    fields["names"].append(name)
    fields["parents"].append(-1 if parent is None else fields["names"].index(parent))
    fields["offsets"].append(np.asarray(offset, dtype=np.float64))
    fields["frames"].append(frame)
    fields["a"].append(np.zeros(3))
    fields["b"].append(np.array([0.0, length, 0.0]))
    fields["ra"].append(r0)
    fields["rb"].append(r1)
    fields["limits"].append(np.zeros((3, 2)) if limits is None else limits)


def hand_skeleton() -> Skeleton:
    """The hand's 17 parts, each a tapered capsule along its bone (the flesh's outline; `scenes.hand_shape` adds
    the palm's breadth), with the joint limits the 18 angles allow (the DIP's its PIP's times the coupling)."""
    fields = {k: [] for k in ("names", "parents", "offsets", "frames", "a", "b", "ra", "rb", "limits")}
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    _part(fields, "forearm", None, (0.0, 0.0, 0.0), identity, 0.0, 0.030, 0.030)
    fields["a"][-1] = np.array([0.0, -0.045, 0.0])
    fields["b"][-1] = np.array([0.0, -0.012, 0.0])
    fields["rb"][-1] = 0.026
    _part(fields, "palm", "forearm", (0.0, 0.0, 0.0), identity, 0.090, 0.016, 0.014)
    fields["a"][-1] = np.array([0.0, 0.010, 0.0])
    (cmc, turn, twist, lengths, radii) = _THUMB
    frame = quat_multiply(quat_from_axis_angle(UNIT_Z, np.radians(turn)),
                          quat_from_axis_angle(UNIT_Y, np.radians(twist)))
    _part(fields, "thumb_0", "palm", cmc, frame, lengths[0], radii[0], radii[1])
    _part(fields, "thumb_1", "thumb_0", (0.0, lengths[0], 0.0), identity, lengths[1], radii[2], radii[3])
    _part(fields, "thumb_2", "thumb_1", (0.0, lengths[1], 0.0), identity, lengths[2], radii[3], radii[4])
    for finger in FINGERS:
        mcp, splay, lengths, radii = _FINGER_SHAPE[finger]
        frame = quat_from_axis_angle(UNIT_Z, np.radians(splay))
        parent, offset = "palm", mcp
        for k in range(3):
            _part(fields, f"{finger}_{k + 1}", parent, offset, frame, lengths[k], radii[k], radii[k + 1])
            parent, offset, frame = f"{finger}_{k + 1}", (0.0, lengths[k], 0.0), identity
    names = tuple(fields["names"])
    limits = np.array(fields["limits"])
    for (_, part, axis, lo, hi) in _ANGLES:
        limits[names.index(part), axis] = np.radians((lo, hi))
    for finger in FINGERS:
        limits[names.index(f"{finger}_3"), 0] = DIP_COUPLING * limits[names.index(f"{finger}_2"), 0]
    return Skeleton(names=names, parents=np.array(fields["parents"], dtype=np.int64),
                    joint_offsets=np.array(fields["offsets"]), frame_rotations=np.array(fields["frames"]),
                    capsule_a=np.array(fields["a"]), capsule_b=np.array(fields["b"]),
                    radius_a=np.array(fields["ra"]), radius_b=np.array(fields["rb"]),
                    joint_lower=limits[:, :, 0], joint_upper=limits[:, :, 1], height=0.19)


def part_angles(skel: Skeleton, angles: np.ndarray) -> np.ndarray:
    """Joint angles of every part (..., P, 3) from the hand's 18 (..., 18), the DIPs following their PIPs. Angles
    outside ANGLE_LIMITS are refused (ValueError naming the first)."""
    angles = np.asarray(angles, dtype=np.float64)
    if angles.shape[-1:] != (len(ANGLE_NAMES),) or not np.isfinite(angles).all():
        raise ValueError(f"hand angles must be finite, (..., {len(ANGLE_NAMES)}); got {angles.shape}")
    slack = 1e-9
    outside = (angles < ANGLE_LIMITS[:, 0] - slack) | (angles > ANGLE_LIMITS[:, 1] + slack)
    if outside.any():
        k = int(np.flatnonzero(outside.reshape(-1, len(ANGLE_NAMES)).any(axis=0))[0])
        raise ValueError(f"hand angle '{ANGLE_NAMES[k]}' outside its limits [{np.degrees(ANGLE_LIMITS[k, 0]):.0f}, "
                         f"{np.degrees(ANGLE_LIMITS[k, 1]):.0f}] degrees")
    out = np.zeros(angles.shape[:-1] + (skel.n_parts, 3))
    for k, (_, part, axis, _, _) in enumerate(_ANGLES):
        out[..., skel.index(part), axis] = angles[..., k]
    for finger in FINGERS:
        out[..., skel.index(f"{finger}_3"), 0] = DIP_COUPLING * out[..., skel.index(f"{finger}_2"), 0]
    return out


def hand_transforms(skel: Skeleton, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (..., P, 4) and translations (..., P, 3) of the parts posed by the 18 angles (..., 18), the
    forearm fixed where it is at rest (the procedural hand's: at the origin)."""
    rotations = joint_quaternions(part_angles(skel, angles))
    return forward_kinematics(skel, skel.joint_offsets[0], rotations)


def fist_angles(closure: float = 1.0) -> np.ndarray:
    """(18,) a fist closed by `closure` in [0, 1]: every flexion at `closure` of its upper limit, the thumb folded
    over the fingers, no abduction or wrist motion."""
    angles = np.zeros(len(ANGLE_NAMES))
    for k, name in enumerate(ANGLE_NAMES):
        if name.endswith("flexion") and not name.startswith("wrist"):
            angles[k] = closure * ANGLE_LIMITS[k, 1]
    abduction = ANGLE_NAMES.index("thumb_cmc_abduction")
    angles[abduction] = closure * ANGLE_LIMITS[abduction, 1]
    return angles
