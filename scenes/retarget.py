"""Retargeting BVH motion capture onto the mannequin, part by part, with rotations only.

Each mannequin part follows the world rotation of one source joint (JOINT_NAMES: the first name the file has),
times a fixed alignment: the part's world rotation while the source stands in its rest pose, or for a limb of a rig
whose rest pose is no standing pose in a frame of the clip (see _alignments), so each bone points where the
source's bone points whatever the limb lengths. Local joint angles then follow parent to child, each from the
parent's achieved rotation (a rotation that a joint's limits cut off is made up further down the chain), are split
as R = Rz Rx Ry (see _decompose) and softly clamped into the joint limits (scenes.motion.soft_limit). Elbows and
knees bend about x only, so the upper arm or thigh is first twisted to put the bend in that plane (see
_twist_to_hinge).

The source's axes (Y-up or Z-up, any facing) are read off its rest skeleton: up from the hips to the head, left
from the right hip to the left one. A leading rest pose (the T-pose that converters put at frame 0) is not played:
the motion starts after it (motion_start), and times count from there. The clip is turned so that the pelvis faces
the mannequin's forward (+z) at the window's first frame and moved so that it starts over the rest root; the root's
horizontal travel is scaled by the ratio of leg lengths (hip to ankle), which also absorbs the file's unit. Its
height is not taken from the file: as for the procedural motions, the lowest foot is kept on the ground. Angles and
travel are lightly smoothed (a Gaussian of half the output frame time, against aliasing; at the file's first and
last frames of motion it holds their values) and resampled with monotone cubic (PCHIP) splines, which stay within
the limits and give exact rates.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from scenes.bvh import MAX_PLAYED_FRAMES, BvhClip, played_frames, world_transforms
from scenes.kinematics import rest_transforms
from scenes.motion import Motion, ground_lift, soft_limit
from scenes.skeleton import Skeleton, default_skeleton

# Source joint names per mannequin part (side suffix dropped), first match wins; compared case-insensitively
# without '_', ' ' and a namespace prefix ("mixamorig:"). {Side} is Left/Right, {s} l/r (CMU's ASF names, Daz/Poser),
# {S} L/R (Reallusion). CMU's releases differ: LeftUpLeg/LeftLeg/LeftFoot and LeftShoulder (collar)/LeftArm/
# LeftForeArm/LeftHand in one, LeftHip/LeftKnee/LeftAnkle and LeftCollar/LeftShoulder (upper arm)/LeftElbow/LeftWrist
# in another, hence LeftShoulder last among the upper-arm names. The Daz/Poser conversion of CMU names the upper arm
# lShldr (its collar is lCollar) and puts a fixed lButtock between hip and lThigh, the hip joint. Reallusion's
# CC_Base rig: its root CC_Base_Hip is the pelvis (the thighs hang from its child CC_Base_Pelvis, turned against it by
# a fixed 11.8° about x, which would tilt a standing mannequin's pelvis by as much); of its back, Waist and Spine01
# bend against each other (about x, by 21-33° and -19° on average over the CMU clips) and the mannequin's spine
# follows their sum; its twist and share bones are left to the joints they ride on. Measured on CMU trial 03_01 in
# both conventions, the mannequin's pelvis, chest and thigh twists agree within 1, 2 and 5° (RMS), its spine 13°
# apart (the rigs' rest backs differ). A skeleton with a single torso joint bends only at the chest: the spine
# then follows the root.
JOINT_NAMES = {
    "pelvis": ("Hips", "Hip", "Pelvis", "Root", "CC_Base_Hip"),
    "spine": ("LowerBack", "Spine", "Abdomen", "CC_Base_Spine01", "Hips", "Hip", "Pelvis", "Root"),
    "chest": ("Chest2", "Spine2", "Thorax", "Spine1", "Chest", "UpperBack", "CC_Base_Spine02"),
    "head": ("Head", "CC_Base_Head"),
    "upper_arm": ("{Side}Arm", "{Side}UpArm", "{Side}UpperArm", "{s}humerus", "{s}Shldr", "CC_Base_{S}_Upperarm",
                  "{Side}Shoulder"),
    "lower_arm": ("{Side}ForeArm", "{Side}LowArm", "{Side}LowerArm", "{s}radius", "{Side}Elbow", "{s}ForeArm",
                  "CC_Base_{S}_Forearm"),
    "hand": ("{Side}Hand", "{Side}Wrist", "{s}wrist", "{s}hand", "CC_Base_{S}_Hand"),
    "thigh": ("{Side}UpLeg", "{Side}UpperLeg", "{Side}Thigh", "{s}femur", "{Side}Hip", "{s}Thigh",
              "CC_Base_{S}_Thigh"),
    "shin": ("{Side}Leg", "{Side}LowLeg", "{Side}LowerLeg", "{Side}Shin", "{s}tibia", "{Side}Knee", "{s}Shin",
             "CC_Base_{S}_Calf"),
    "foot": ("{Side}Foot", "{s}foot", "{Side}Ankle", "CC_Base_{S}_Foot"),
}
# The part whose joint ends each part's bone. The head's bone is its neck, from the chest's joint to its own (the
# joints below a head lead to eyes, jaw and face, forward of it, as often as to its top: Daz/Poser, CC_Base); hands
# and feet end at their capsule's far end (capsule_b), in the source at the farthest End Site below them.
_BONE_END = {"spine": "chest", "chest": "head", "upper_arm": "lower_arm", "lower_arm": "hand", "thigh": "shin",
             "shin": "foot"}
_SIDES = {"_l": {"Side": "Left", "s": "l", "S": "L"}, "_r": {"Side": "Right", "s": "r", "S": "R"}}
HINGE_FADE = np.radians(20.0)  # bend of an elbow or knee below which its parent's twist is left as the source's
GIMBAL_FADE = np.radians(20.0)  # distance from gimbal lock (flexion ±90°) within which the lean z fades to 0
# Frame 0 is a rest pose put before the motion where every source joint that drives the mannequin (the file's root
# aside: it carries the heading) is within REST_TOLERANCE of its rest rotation. Measured: the T-pose frames of the
# 167 Daz/Poser CMU clips come within 3.6-10.6° (a thigh or shin the farthest); from the 10th frame on, no frame of
# any shared clip comes within 30° (the CMU 131 walk: 43°, its frame 0 96°; CC_Base clips, whose zero pose is no
# standing pose: 114°, their frame 0 more than 160°).
REST_TOLERANCE = np.radians(20.0)
# Where frame 0 is a rest pose the motion starts REST_LEAD_FRAMES later: converters blend out of it over the next
# frames. Measured on the 167 Daz/Poser CMU clips: the largest joint rotation from one frame to the next is 11-53°
# out of frames 0-3 (medians 24, 25, 23, 16°) where a clip's median is 0.4-14° (median 2.3°); it exceeds 3 times
# the clip's median out of frames 0-3 in 98-99% of the clips, frame 4 in 50%, then rings (6: 22%, 7: 8%) and from
# frame 8 on in 1%, as later frames do. Dropping 8 frames from a clip without such a blend costs 0.07 s at 120 fps.
REST_LEAD_FRAMES = 8
# The root's yaw limit while retargeting (radians): far beyond any heading a clip reaches, so that soft_limit leaves
# it as it is (the mannequin's own ±90° pelvis yaw bounds its procedural motions; on the shared CMU library it
# clamped 47 % of 4-second windows, 149 of them dance, with limbs then 120-160° off).
FREE_HEADING = 1.0e4
# A bone is aligned in the source's rest pose where that takes a turn of at most REFERENCE_LIMIT, else in a frame
# of the clip (see _alignments).
REFERENCE_LIMIT = np.radians(90.0)


def joint_map(clip: BvhClip, skel: Skeleton) -> dict[str, int]:
    """The source joint (index into clip.names) of every mannequin part; a ValueError names the parts (and the
    joint names tried) that the file lacks."""
    normalised = {_normalise(n): j for j, n in reversed(list(enumerate(clip.names)))}
    mapping, missing = {}, []
    for part in skel.names:
        candidates = _candidates(part)
        found = [normalised[_normalise(c)] for c in candidates if _normalise(c) in normalised]
        if found:
            mapping[part] = found[0]
        else:
            missing.append(f"{part} ({'/'.join(candidates) or 'no known names'})")
    if missing:
        raise ValueError(f"cannot map BVH '{clip.name}' onto the mannequin: no joint for {', '.join(missing)}")
    return mapping


def motion_start(clip: BvhClip) -> int:
    """Index of the clip's first frame of motion: REST_LEAD_FRAMES where its frame 0 is a rest pose (a T-pose put
    before the motion, see REST_TOLERANCE), else 0. Judged on the joints that drive the mannequin, so a clip that
    cannot be mapped onto it is joint_map's ValueError."""
    joints = sorted(set(joint_map(clip, default_skeleton()).values()) - {0})   # part names: any height's
    at_rest = Rotation.from_quat(clip.rotations[0, joints]).magnitude().max() <= REST_TOLERANCE
    return min(REST_LEAD_FRAMES, clip.n_frames - 1) if at_rest else 0


def retarget(clip: BvhClip, skel: Skeleton, fps: float, start: float | None = None,
             end: float | None = None) -> Motion:
    """The clip's motion between `start` and `end` seconds (default: all of it), counted from its first frame of
    motion (motion_start: a leading rest pose is not played), as a mannequin Motion at `fps`, starting over the
    rest root and facing +z, with the lowest foot on the ground (see the module docstring). The Motion is raw: it
    starts and ends in the clip's poses, not at rest (settle_frames = blend_frames = 0). Its kind names the clip:
    "bvh:NAME", or "bvh:NAME@START-END" for a window."""
    first_motion = motion_start(clip)
    lead = first_motion * clip.frame_time   # seconds of the file before its motion
    duration = clip.duration - lead
    windowed = start is not None or end is not None
    start = 0.0 if start is None else float(start)
    end = duration if end is None else float(end)
    kind = f"bvh:{clip.name}" + (f"@{start:g}-{end:g}" if windowed else "")
    if not fps > 0 or not 0.0 <= start <= end - clip.frame_time or end > duration + 1e-9:
        raise ValueError(f"BVH '{clip.name}': need fps > 0 and 0 <= start < end <= {duration:.3f} s (of motion, "
                         f"from frame {first_motion}) with at least one frame between them; got fps {fps}, "
                         f"start {start}, end {end}")
    frames = played_frames(end - start, fps)
    if frames > MAX_PLAYED_FRAMES:      # checked before the resampled arrays exist (Frame Time 100: 5.96 M frames)
        raise ValueError(f"BVH '{clip.name}': {end - start:.6g} s of motion at {fps:g} frames/s play {frames:,} "
                         f"frames, more than {MAX_PLAYED_FRAMES:,}")
    begin, finish = start + lead, end + lead   # seconds in the file
    sigma = 0.5 / fps  # seconds
    pad = int(np.ceil(4 * sigma / clip.frame_time))
    first = max(int(np.floor(begin / clip.frame_time)) - pad, first_motion)
    last = min(int(np.ceil(finish / clip.frame_time)) + pad, clip.n_frames - 1)
    angles, travel = _source_frames(clip, skel, slice(first, last + 1), int(round(begin / clip.frame_time)) - first)
    times = (first + np.arange(last - first + 1)) * clip.frame_time
    smooth = {name: PchipInterpolator(times, gaussian_filter1d(x, sigma / clip.frame_time, axis=0, mode="nearest"),
                                      axis=0) for name, x in (("angles", angles), ("travel", travel))}
    t = begin + np.arange(frames) / fps
    joint_angles, joint_angle_rates = smooth["angles"](t), smooth["angles"].derivative()(t)
    root_position = skel.joint_offsets[0] + smooth["travel"](t) - smooth["travel"](begin)
    root_velocity = smooth["travel"].derivative()(t)
    lift, lift_rate = ground_lift(skel, root_position, root_velocity, joint_angles, joint_angle_rates, fps)
    root_position[:, 1] += lift
    root_velocity[:, 1] += lift_rate
    return Motion(kind=kind, fps=float(fps), seed=0, settle_frames=0, blend_frames=0,
                  root_position=root_position, root_velocity=root_velocity, joint_angles=joint_angles,
                  joint_angle_rates=joint_angle_rates)


def _source_frames(clip: BvhClip, skel: Skeleton, frames: slice, t0: int) -> tuple[np.ndarray, np.ndarray]:
    """Mannequin joint angles (T, P, 3) and horizontal root travel (T, 3) for the selected source frames, turned
    and moved so that at frame t0 (counted within the selection) the pelvis faces +z and the travel is zero."""
    parts = joint_map(clip, skel)
    axes = _source_axes(clip, parts, skel)
    offsets = _alignments(clip, parts, skel, axes)
    rotation, position = world_transforms(clip, frames)
    target = {p: axes * Rotation.from_quat(rotation[:, j]) * offsets[p] for p, j in parts.items()}
    root = skel.names[0]
    forward = target[root][t0].apply([0.0, 0.0, 1.0])
    face_forward = Rotation.from_rotvec([0.0, -np.arctan2(forward[0], forward[2]), 0.0])
    angles = _joint_angles(skel, {p: face_forward * r for p, r in target.items()})
    root_position = position[:, parts[root]]
    travel = face_forward.apply(axes.apply(root_position - root_position[t0])) * _leg_length_ratio(clip, parts, skel)
    travel[:, 1] = 0.0
    return angles, travel


def _normalise(name: str) -> str:
    return name.rsplit(":", 1)[-1].replace("_", "").replace(" ", "").lower()


def _split_side(part: str) -> tuple[str, str]:
    """('thigh', '_l') for 'thigh_l', ('head', '') for 'head'."""
    return (part[:-2], part[-2:]) if part[-2:] in _SIDES else (part, "")


def _candidates(part: str) -> tuple[str, ...]:
    """Source joint names for a mannequin part name such as 'thigh_l'."""
    base, side = _split_side(part)
    return tuple(n.format(**_SIDES.get(side, {"Side": "", "s": "", "S": ""})) for n in JOINT_NAMES.get(base, ()))


def _bone_end(part: str) -> str | None:
    """The mannequin part whose joint ends `part`'s bone, or None for a part that ends at its capsule."""
    base, side = _split_side(part)
    return _BONE_END[base] + side if base in _BONE_END else None


def _source_axes(clip: BvhClip, parts: dict[str, int], skel: Skeleton) -> Rotation:
    """The rotation from the source's axes to the mannequin's: it takes the source's rest-pose up (hips to head)
    onto the mannequin's, and its left (right hip to left hip) as close as it goes."""
    source = _body_axes(clip.rest_positions(), parts)
    if np.isnan(source).any():
        raise ValueError(f"BVH '{clip.name}': cannot tell left from up in the rest pose (hips and head in line)")
    return Rotation.from_matrix(_mannequin_axes(skel).T @ source)


def _reference_frame(clip: BvhClip, parts: dict[str, int], skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (J, 4) and positions (J, 3) of the frame whose bones come closest to the mannequin's rest
    pose on average, of those whose bones all lie within REFERENCE_LIMIT of it (each in its body's axes)."""
    rotation, position = world_transforms(clip)
    angles = _bone_angles(clip, parts, skel, rotation, position)
    usable = angles.max(axis=1) <= REFERENCE_LIMIT
    if not usable.any():
        raise ValueError(f"BVH '{clip.name}': its rest pose is no standing pose and no frame of it comes within "
                         f"{np.degrees(REFERENCE_LIMIT):.0f}° of the mannequin's rest pose in every bone")
    k = int(np.argmin(np.where(usable, angles.mean(axis=1), np.inf)))
    return rotation[k], position[k]


def _bone_angles(clip: BvhClip, parts: dict[str, int], skel: Skeleton, rotation: np.ndarray,
                 position: np.ndarray) -> np.ndarray:
    """Angles (..., P - 1) between the bones of the source posed by `rotation` (..., J, 4) and `position`
    (..., J, 3) and the mannequin's bones at rest (the root's aside), each in its body's axes; inf where those are
    undefined."""
    mannequin_rotation, _ = rest_transforms(skel)
    body, own_body = _body_axes(position, parts), _mannequin_axes(skel)
    angles = []
    for p, part in enumerate(skel.names[1:], start=1):
        bone = np.einsum("...ij,...j->...i", body, _source_bone(clip, parts, part, rotation, position))
        own = own_body @ Rotation.from_quat(mannequin_rotation[p]).apply(_local_bone(skel, p))
        angles.append(np.arccos(np.clip(bone @ own / np.linalg.norm(bone, axis=-1), -1.0, 1.0)))
    angles = np.stack(angles, axis=-1)
    return np.where(np.isnan(angles), np.inf, angles)


def _body_axes(points: np.ndarray, index: dict[str, int]) -> np.ndarray:
    """Rows (..., 3, 3) left, up, forward of a body whose joints are at `points` (..., J, 3), `index` naming its
    parts' joints: up from between the hips to the head, left from the right hip to the left one made square to
    up. NaN where the hips and the head are (nearly) in line."""
    hips = points[..., index["thigh_l"], :], points[..., index["thigh_r"], :]
    up, left = points[..., index["head"], :] - 0.5 * (hips[0] + hips[1]), hips[0] - hips[1]
    up, left = (v / np.linalg.norm(v, axis=-1, keepdims=True) for v in (up, left))
    forward = np.cross(left, up)
    length = np.linalg.norm(forward, axis=-1, keepdims=True)
    forward = np.where(length > 0.5, forward / length, np.nan)
    return np.stack([np.cross(up, forward), up, forward], axis=-2)


def _mannequin_axes(skel: Skeleton) -> np.ndarray:
    """The mannequin's body axes at rest (the identity: it faces +z with its left on +x)."""
    return _body_axes(rest_transforms(skel)[1], _own_index(skel))


def _own_index(skel: Skeleton) -> dict[str, int]:
    """The mannequin's parts by name, shaped like a joint map."""
    return {part: p for p, part in enumerate(skel.names)}


def _alignments(clip: BvhClip, parts: dict[str, int], skel: Skeleton, axes: Rotation) -> dict[str, Rotation]:
    """Per part, the fixed rotation with which it follows its source joint: its world rotation is
    axes * W * alignment, W the joint's world rotation in the file. It makes the part's world rotation, with the
    source standing in its rest pose, the mannequin's rest pose with each joint turned, parent to child, by the
    smallest rotation that lays the part's bone along the source's bone (in the mannequin's axes). Turning joint by
    joint keeps a source joint's local rotation meaning what it means to the mannequin's joint: where the source's
    rest legs splay outward, the aligned thighs splay and the feet roll with them, so a source ankle at rest leaves
    the foot square to the shin. Where that turn exceeds REFERENCE_LIMIT (a rig whose zero pose is no standing
    pose, such as CC_Base's with every bone along +y: the smallest rotation between near-opposite bones leaves the
    limb's twist to chance), the bone is laid along the source's in a frame of the clip instead (_reference_frame),
    whose twist of that bone becomes the mannequin's untwisted one."""
    rest = np.tile([0.0, 0.0, 0.0, 1.0], (len(clip.names), 1)), clip.rest_positions()
    reference = None
    alignments = {}
    for p, (part, parent) in enumerate(zip(skel.names, skel.parents)):
        if parent < 0:
            alignments[part] = axes.inv() * Rotation.from_quat(skel.frame_rotations[p])
            continue
        pose = rest
        world, turn = _laid_along(clip, parts, skel, axes, alignments, p, pose)
        if turn > REFERENCE_LIMIT:
            reference = reference or _reference_frame(clip, parts, skel)
            pose = reference
            world, _ = _laid_along(clip, parts, skel, axes, alignments, p, pose)
        alignments[part] = Rotation.from_quat(pose[0][parts[part]]).inv() * axes.inv() * world
    return alignments


def _laid_along(clip: BvhClip, parts: dict[str, int], skel: Skeleton, axes: Rotation,
                alignments: dict[str, Rotation], p: int, pose: tuple[np.ndarray, np.ndarray]) -> tuple[Rotation, float]:
    """Part p's world rotation with the source in `pose` (world rotations (J, 4), positions (J, 3)): its parent's
    (by its alignment) and its rest frame turned by the smallest rotation that lays its bone along the source's;
    and that turn's angle."""
    rotation, position = pose
    part, parent = skel.names[p], skel.names[skel.parents[p]]
    base = axes * Rotation.from_quat(rotation[parts[parent]]) * alignments[parent] * Rotation.from_quat(
        skel.frame_rotations[p])
    bone = axes.apply(_source_bone(clip, parts, part, rotation, position))
    if not np.linalg.norm(bone) > 0:
        raise ValueError(f"BVH '{clip.name}': joint '{clip.names[parts[part]]}' has a zero-length bone for mannequin "
                         f"part {part}")
    turn, _ = Rotation.align_vectors([base.inv().apply(bone)], [_local_bone(skel, p)])
    return base * turn, float(turn.magnitude())


def _source_bone(clip: BvhClip, parts: dict[str, int], part: str, rotation: np.ndarray,
                 position: np.ndarray) -> np.ndarray:
    """The bone (..., 3) of mannequin part `part` in the source posed by world `rotation` (..., J, 4) and
    `position` (..., J, 3): to the joint that ends it, the head's along the neck, else to the farthest End Site
    below its joint."""
    joint = parts[part]
    if part == "head":
        return position[..., joint, :] - position[..., parts["chest"], :]
    end = _bone_end(part)
    if end is not None:
        return position[..., parts[end], :] - position[..., joint, :]
    site, offset = _farthest_end_site(clip, joint)
    tip = position[..., site, :] + Rotation.from_quat(rotation[..., site, :]).apply(offset)
    return tip - position[..., joint, :]


def _farthest_end_site(clip: BvhClip, joint: int) -> tuple[int, np.ndarray]:
    """The joint holding the End Site below `joint` (itself included) farthest from it in the rest pose, and the
    site's offset in that joint's frame."""
    rest = clip.rest_positions()
    below = {joint}
    for j, parent in enumerate(clip.parents):
        if parent in below:
            below.add(j)
    sites = [(j, offset) for j, offset in clip.end_sites.items() if j in below]
    if not sites:
        raise ValueError(f"BVH '{clip.name}': no End Site below joint '{clip.names[joint]}' to give its direction")
    return max(sites, key=lambda site: np.linalg.norm(rest[site[0]] + site[1] - rest[joint]))


def _joint_angles(skel: Skeleton, target: dict[str, Rotation]) -> np.ndarray:
    """Joint angles (F, P, 3) that give each part its target world rotation as far as the joint limits allow,
    after twisting the parents of hinges; each joint starts from its parent's achieved rotation."""
    target = dict(target)
    for c, parent in enumerate(skel.parents):
        mid_flexion = 0.5 * (skel.joint_lower[c, 0] + skel.joint_upper[c, 0])
        if skel.joint_lower[c, 2] == skel.joint_upper[c, 2] and np.sin(mid_flexion) != 0.0:
            part, child = skel.names[parent], skel.names[c]
            target[part] = _twist_to_hinge(target[part], target[child].apply(_local_bone(skel, c)), mid_flexion)
    angles = np.zeros((len(target[skel.names[0]]), skel.n_parts, 3))
    achieved = []
    for p, (part, parent) in enumerate(zip(skel.names, skel.parents)):
        base = Rotation.from_quat(skel.frame_rotations[p])
        lower, upper = skel.joint_lower[p].copy(), skel.joint_upper[p].copy()
        if parent >= 0:
            base = achieved[parent] * base
        else:   # the root's yaw is the heading, not a joint: a dancer turns any number of times
            lower[1], upper[1] = -FREE_HEADING, FREE_HEADING
        raw = np.unwrap(_decompose(base.inv() * target[part], lower, upper), axis=0)
        angles[:, p] = soft_limit(raw, np.zeros_like(raw), lower, upper)[0]
        achieved.append(base * Rotation.from_euler("ZXY", angles[:, p, [2, 0, 1]]))
    return angles


def _twist_to_hinge(parent: Rotation, child_bone: np.ndarray, mid_flexion: float) -> Rotation:
    """The parent's world rotation twisted about its bone (its y axis) so that the child's bone (world direction
    per frame) lies in the plane in which the child's hinge bends: about x, toward the side its mid flexion
    `mid_flexion` (radians) swings it. A source elbow may bend about another axis of its own, with the upper arm
    twisted to match (CMU's do); the mannequin's cannot. Near a straight limb the bending plane is undefined, so
    the twist fades out as the bend falls below HINGE_FADE."""
    x, _, z = parent.inv().apply(child_bone).T
    side = -np.sign(np.sin(mid_flexion))  # the direction (+z or -z) the child swings to when it bends
    u = np.clip(np.hypot(x, z) / np.sin(HINGE_FADE), 0.0, 1.0)
    twist = np.arctan2(side * x, side * z) * u * u * (3.0 - 2.0 * u)
    return parent * Rotation.from_rotvec(twist[:, None] * np.array([0.0, 1.0, 0.0]))


def _local_bone(skel: Skeleton, p: int) -> np.ndarray:
    """Unit direction of part p's bone in its own frame: to the joint that ends it, the head's along the neck (from
    the chest's joint to its own), or to its capsule's far end."""
    end = _bone_end(skel.names[p])
    if skel.names[p] == "head":
        bone = Rotation.from_quat(skel.frame_rotations[p]).inv().apply(skel.joint_offsets[p])
    else:
        bone = skel.capsule_b[p] if end is None else skel.joint_offsets[skel.index(end)]
    return bone / np.linalg.norm(bone)


def _decompose(rotation: Rotation, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Angles (F, 3) as (x, y, z) with R = Rz(z) Rx(x) Ry(y) for a joint with limits [lower, upper], continuous
    in time where the exact Euler angles are not.

    The swing Rz Rx is read off where R takes the bone axis (-y): z is the bone's sideways lean, taken from
    whichever of its two values (z, z + pi) lies nearer the z limits, and x its flexion over the full circle, so
    knees, elbows, arms and thighs can swing past 90°. The twist y is what remains about the bone. Near gimbal
    lock (the bone along z, x = ±90°) z and y turn about the same axis and the exact split swings wildly: there
    z fades to 0 (within GIMBAL_FADE of the lock) and the twist takes the rest. A joint whose z range is empty
    (elbow, knee) is a hinge with a twist and keeps z = 0."""
    bone = rotation.apply([0.0, -1.0, 0.0])
    if lower[2] == upper[2]:
        z = np.zeros(len(bone))
    else:
        z = np.arctan2(bone[:, 0], -bone[:, 1])
        flipped = np.angle(np.exp(1j * (z + np.pi)))
        outside = [np.maximum(lower[2] - a, 0.0) + np.maximum(a - upper[2], 0.0) for a in (z, flipped)]
        u = np.clip(np.hypot(bone[:, 0], bone[:, 1]) / np.sin(GIMBAL_FADE), 0.0, 1.0)
        z = np.where(outside[1] < outside[0], flipped, z) * u * u * (3.0 - 2.0 * u)
    leaned = Rotation.from_rotvec(-z[:, None] * np.array([0.0, 0.0, 1.0])).apply(bone)
    x = np.arctan2(-leaned[:, 2], -leaned[:, 1])
    twist = (Rotation.from_euler("ZX", np.stack([z, x], axis=1)).inv() * rotation).as_quat()
    y = np.angle(np.exp(2j * np.arctan2(twist[:, 1], twist[:, 3])))
    return np.stack([x, y, z], axis=1)


def _leg_length_ratio(clip: BvhClip, parts: dict[str, int], skel: Skeleton) -> float:
    """Mannequin leg length over source leg length (hip to knee to ankle, both legs averaged)."""
    def leg_length(points: np.ndarray, index: dict[str, int]) -> float:
        legs = [points[[index[f"thigh{s}"], index[f"shin{s}"], index[f"foot{s}"]]] for s in _SIDES]
        return float(np.mean([np.linalg.norm(np.diff(leg, axis=0), axis=1).sum() for leg in legs]))
    return leg_length(rest_transforms(skel)[1], _own_index(skel)) / leg_length(clip.rest_positions(), parts)
