"""Retargeting BVH onto the mannequin: a round trip through known joint angles written as BVH files in four naming
conventions (two of CMU's, Daz/Poser's, CC_Base's whose zero pose has its limbs up), Y-up and Z-up, several units
and every rotation order; a leading rest pose not played; resampling and windows; limits; a clear error for an
unmappable file; and the shared CMU clips (skipped where ../shared/mocap is absent)."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bvh_files import Joint, write_bvh
from scenes.bvh import UNITS, read_bvh
from scenes.capsules import capsules_world
from scenes.kinematics import forward_kinematics, joint_quaternions, rest_transforms
from scenes.motion import body_state
from scenes.retarget import REST_LEAD_FRAMES, joint_map, motion_start, retarget
from scenes.skeleton import default_skeleton
from shared_mocap import MOCAP, manifest

SKEL = default_skeleton()
CMU_WALK = MOCAP / "cmu_131_01_walk.bvh"
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
# Joint names per mannequin part in two of CMU's releases, its Daz/Poser conversion and Reallusion's CC_Base rig,
# and the collar joint each puts before the upper arm.
CONVENTIONS = {
    "motionbuilder": {"pelvis": "Hips", "spine": "Spine", "chest": "Spine1", "head": "Head", "collar": "{Side}Shoulder",
                      "upper_arm": "{Side}Arm", "lower_arm": "{Side}ForeArm", "hand": "{Side}Hand",
                      "thigh": "{Side}UpLeg", "shin": "{Side}Leg", "foot": "{Side}Foot"},
    "3dsmax": {"pelvis": "Hips", "spine": "lowerback", "chest": "Chest2", "head": "Head", "collar": "{Side}Collar",
               "upper_arm": "{Side}Shoulder", "lower_arm": "{Side}Elbow", "hand": "{Side}Wrist",
               "thigh": "{Side}Hip", "shin": "{Side}Knee", "foot": "{Side}Ankle"},
    "daz": {"pelvis": "hip", "spine": "abdomen", "chest": "chest", "head": "head", "collar": "{s}Collar",
            "upper_arm": "{s}Shldr", "lower_arm": "{s}ForeArm", "hand": "{s}Hand", "thigh": "{s}Thigh",
            "shin": "{s}Shin", "foot": "{s}Foot"},
    "cc_base": {"pelvis": "CC_Base_Hip", "spine": "CC_Base_Spine01", "chest": "CC_Base_Spine02",
                "head": "CC_Base_Head", "collar": "CC_Base_{S}_Clavicle", "upper_arm": "CC_Base_{S}_Upperarm",
                "lower_arm": "CC_Base_{S}_Forearm", "hand": "CC_Base_{S}_Hand", "thigh": "CC_Base_{S}_Thigh",
                "shin": "CC_Base_{S}_Calf", "foot": "CC_Base_{S}_Foot"},
}
# Joints a convention puts above a part, at its parent's joint, with no rotation of their own: Daz/Poser's neck
# and buttocks, CC_Base's waist and a neck twist bone.
ABOVE = {"daz": {"head": "neck", "thigh": "{s}Buttock"},
         "cc_base": {"spine": "CC_Base_Waist", "head": "CC_Base_NeckTwist01"}}
# How a part's joint is turned in the zero pose (all local rotations 0) against the mannequin's rest, about the
# mannequin's forward axis: CC_Base's zero pose has every limb pointing up.
BIND = {"cc_base": {"thigh_l": 180, "shin_l": 180, "foot_l": 180, "thigh_r": 180, "shin_r": 180, "foot_r": 180,
                    "upper_arm_l": -135, "lower_arm_l": -135, "hand_l": -135,
                    "upper_arm_r": 135, "lower_arm_r": 135, "hand_r": 135}}
SIDE_WORDS = {"_l": {"Side": "Left", "s": "l", "S": "L"}, "_r": {"Side": "Right", "s": "r", "S": "R"},
              "": {"Side": "", "s": "", "S": ""}}
EYES = ((0.03, 0.07, 0.08), (-0.03, 0.07, 0.08))   # Daz/Poser's head ends in eyes (metres from its joint)
FPS, SECONDS, OMEGA = 120.0, 2.0, 2 * np.pi * 0.4


def split_side(part: str) -> tuple[str, str]:
    return (part[:-2], part[-2:]) if part[-2:] in ("_l", "_r") else (part, "")


def source_name(convention: str, part: str) -> str:
    base, side = split_side(part)
    return CONVENTIONS[convention][base].format(**SIDE_WORDS[side])


def known_motion(seed: int = 0, rest_at: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (T,), joint angles (T, P, 3) and their rates: sinusoids inside the limits (shrunk by 10% of each
    range, with |x| <= 60° for joints that also lean, away from gimbal lock); the pelvis starts at rest. With
    `rest_at` (seconds) the angles are scaled down to the rest pose at that time (the rates are then not theirs)."""
    t = np.arange(int(SECONDS * FPS) + 1) / FPS
    lower = SKEL.joint_lower + 0.1 * (SKEL.joint_upper - SKEL.joint_lower)
    upper = SKEL.joint_upper - 0.1 * (SKEL.joint_upper - SKEL.joint_lower)
    leans = SKEL.joint_lower[:, 2] < SKEL.joint_upper[:, 2]
    lower[leans, 0] = np.maximum(lower[leans, 0], np.radians(-60))
    upper[leans, 0] = np.minimum(upper[leans, 0], np.radians(60))
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, lower.shape)
    phase[0] = 0.0
    mid, amplitude = 0.5 * (lower + upper), 0.5 * (upper - lower)
    mid[0] = 0.0
    amplitude[0] = np.minimum(upper[0], -lower[0])
    arg = OMEGA * t[:, None, None] + phase
    angles = mid + amplitude * np.sin(arg)
    if rest_at is not None:
        angles *= 1.0 - np.exp(-(((t - rest_at) / 0.3) ** 2))[:, None, None]
    return t, angles, amplitude * OMEGA * np.cos(arg)


def part_ends(convention: str, base: str, end: np.ndarray, axes: Rotation) -> tuple[np.ndarray | None, list]:
    """How a head, hand or foot whose capsule ends at `end` (file axes, metres from its joint) ends in a
    convention's file: its own End Site, and joints below it (offset, End Site)."""
    if convention == "daz" and base == "head":
        return None, [(axes.apply(eye), axes.apply([0.01, 0.0, 0.0])) for eye in EYES]
    if convention == "cc_base":
        return None, [(end, np.zeros(3))]
    return end, []


def mannequin_bvh(path: Path, convention: str, angles: np.ndarray, root: np.ndarray, axes: Rotation,
                  unit: float) -> Path:
    """A BVH file of the mannequin playing `angles` (T, P, 3) with the pelvis at `root` (T, 3) (see
    mannequin_channels)."""
    return write_bvh(path, *mannequin_channels(convention, angles, root, axes, unit), 1 / FPS)


def mannequin_channels(convention: str, angles: np.ndarray, root: np.ndarray, axes: Rotation,
                       unit: float) -> tuple[list[Joint], np.ndarray]:
    """The joints and channel values (T, C) of the mannequin's rest skeleton playing `angles` (T, P, 3) with the
    pelvis at `root` (T, 3), in the file axes `axes` (a rotation from the mannequin's) and `unit` metres per unit,
    built as `convention` builds a skeleton: its names, collars between chest and upper arms, the joints it puts
    above parts (ABOVE), its zero pose (BIND) and how heads, hands and feet end (End Sites at the capsules' far
    ends; Daz/Poser's head in eyes; CC_Base's in joints with End Sites of zero offset). Each part's joint turns
    in the world as the mannequin part relative to its rest, times its bind."""
    rest_rotation, rest_position = rest_transforms(SKEL)
    rotation, _ = forward_kinematics(SKEL, root, joint_quaternions(angles))
    joints, moves, binds, index = [], [], [], {}

    def add(name: str, parent: int, offset: np.ndarray, move: Rotation, bind: Rotation,
            end_site: np.ndarray | None = None) -> int:
        """A joint `offset` (file axes, metres, the mannequin at rest) from source joint `parent`, turning in the
        world by `move` (T) from its zero pose turned by `bind`; lengths in its parent's or its own zero frame."""
        into_parent = Rotation.identity() if parent < 0 else binds[parent].inv()
        end = None if end_site is None else tuple(bind.inv().apply(end_site) / unit)
        joints.append(Joint(name, parent, tuple(into_parent.apply(offset) / unit), ORDERS[len(joints) % 6],
                            has_position=parent < 0, end_site=end))
        moves.append(move)
        binds.append(bind)
        return len(joints) - 1

    for p, (part, parent) in enumerate(zip(SKEL.names, SKEL.parents)):
        base, side = split_side(part)
        world = axes * Rotation.from_quat(rotation[:, p]) * Rotation.from_quat(rest_rotation[p]).inv() * axes.inv()
        bind = axes * Rotation.from_euler("z", BIND.get(convention, {}).get(part, 0), degrees=True) * axes.inv()
        offset = axes.apply(rest_position[p] - (0 if parent < 0 else rest_position[parent]))
        source_parent = -1 if parent < 0 else index[SKEL.names[parent]]
        above = [source_name(convention, "collar" + side)] if base == "upper_arm" else []
        if base in ABOVE.get(convention, {}):
            above.append(ABOVE[convention][base].format(**SIDE_WORDS[side]))
        for name in above:   # at the parent's joint, turning with it
            source_parent = add(name, source_parent, np.zeros(3), moves[source_parent], binds[source_parent])
        site, tips = None, []
        if base in ("head", "hand", "foot"):
            site, tips = part_ends(convention, base, axes.apply(
                Rotation.from_quat(rest_rotation[p]).apply(SKEL.capsule_b[p])), axes)
        index[part] = add(source_name(convention, part), source_parent, offset, world, bind, site)
        for k, (tip, tip_site) in enumerate(tips):
            add(f"{source_name(convention, part)}Tip{k}", index[part], tip, world, bind, tip_site)
    worlds = [move * bind for move, bind in zip(moves, binds)]
    local = [w if joint.parent < 0 else worlds[joint.parent].inv() * w for joint, w in zip(joints, worlds)]
    columns = [axes.apply(root) / unit]
    columns += [r.as_euler(j.rotation_order, degrees=True) for j, r in zip(joints, local)]
    return joints, np.concatenate(columns, axis=1)


def within_limits(motion) -> bool:
    """Every joint angle within the mannequin's limits, but for the root's yaw: the heading, left free."""
    angles, lower, upper = motion.joint_angles, SKEL.joint_lower.copy(), SKEL.joint_upper.copy()
    lower[0, 1], upper[0, 1] = -np.inf, np.inf
    return bool(((angles >= lower - 1e-9) & (angles <= upper + 1e-9)).all())


# Writing a root that turns through 90 degrees about the middle axis of its Euler order is gimbal lock for the file's
# angles (scipy warns); the rotation they compose is still exact, which is all the file must hold.
@pytest.mark.filterwarnings("ignore:Gimbal lock detected")
def test_the_heading_turns_freely_where_the_other_joints_are_clamped(tmp_path):
    """A clip that turns round twice keeps turning on the mannequin (a ±90° pelvis yaw would stop it at a quarter
    turn and leave every limb facing the wrong way)."""
    t, angles, _ = known_motion(seed=2)
    angles = angles * 0.0
    turns = np.linspace(0.0, 4 * np.pi, len(t))
    angles[:, 0, 1] = turns                                   # the root's yaw: two whole turns
    root = np.stack([np.zeros_like(t), np.full_like(t, 0.9), np.zeros_like(t)], axis=1)
    clip = read_bvh(mannequin_bvh(tmp_path / "spin.bvh", "3dsmax", angles, root, Rotation.identity(), 1.0))
    motion = retarget(clip, SKEL, 60.0)
    yaw = motion.joint_angles[:, 0, 1]
    # Two turns less what the light smoothing takes off the ends; a ±90° yaw would span pi at most.
    assert yaw.max() - yaw.min() > 3.8 * np.pi and np.all(np.diff(yaw) > -1e-9) and within_limits(motion)


def lowest_foot_point(motion) -> np.ndarray:
    """Height (F,) of the lowest point of the two foot capsules."""
    a, b, ra, rb = capsules_world(SKEL, body_state(SKEL, motion).transforms)
    feet = [SKEL.index("foot_l"), SKEL.index("foot_r")]
    return np.minimum(a[:, feet, 1] - ra[:, feet], b[:, feet, 1] - rb[:, feet]).min(axis=1)


@pytest.mark.parametrize("convention, axes, unit", [
    ("motionbuilder", Rotation.identity(), "m"),
    ("3dsmax", Rotation.from_euler("ZX", [70, 90], degrees=True), "cm"),   # Z-up, facing turned by 70°
    ("3dsmax", Rotation.identity(), "CMU ASF unit"),
    ("daz", Rotation.from_euler("ZX", [-40, 90], degrees=True), "inch"),     # Z-up; its head ends in eyes
])
def test_round_trip_through_known_angles(tmp_path, convention, axes, unit):
    t, angles, _ = known_motion()
    root = np.stack([0.05 * np.sin(OMEGA * t), np.full_like(t, 0.9), 0.6 * t], axis=1)
    clip = read_bvh(mannequin_bvh(tmp_path / f"{convention}.bvh", convention, angles, root, axes, UNITS[unit]))
    assert clip.unit_scale == UNITS[unit]
    assert {p: clip.names[j] for p, j in joint_map(clip, SKEL).items()} == {
        p: source_name(convention, p) for p in SKEL.names}
    motion = retarget(clip, SKEL, FPS)
    assert motion.n_frames == len(t) and motion.fps == FPS and motion.kind == f"bvh:{convention}"
    # The anti-aliasing smoothing holds the file's first and last values, a small bias in the frames next to them.
    np.testing.assert_allclose(motion.joint_angles[3:-3], angles[3:-3], atol=5e-4)
    np.testing.assert_allclose(motion.joint_angles, angles, atol=5e-3)
    np.testing.assert_allclose(motion.root_position[:, [0, 2]], root[:, [0, 2]] - root[0, [0, 2]], atol=2e-3)
    _, expected = forward_kinematics(SKEL, root, joint_quaternions(angles))
    _, achieved = forward_kinematics(SKEL, motion.root_position, motion.joint_rotations)
    np.testing.assert_allclose((achieved - achieved[:, :1])[3:-3], (expected - expected[:, :1])[3:-3], atol=1e-3)
    assert np.abs(lowest_foot_point(motion)).max() < 0.02   # on the ground as the procedural motions (2 cm)


def test_resampling_and_window(tmp_path):
    t, angles, rates = known_motion(seed=1)
    angles[:, 0], rates[:, 0] = 0.0, 0.0   # the pelvis only turns about y
    angles[:, 0, 1], rates[:, 0, 1] = 0.3 * np.sin(OMEGA * t), 0.3 * OMEGA * np.cos(OMEGA * t)
    root = np.stack([np.zeros_like(t), np.full_like(t, 0.9), 0.5 * t], axis=1)
    clip = read_bvh(mannequin_bvh(tmp_path / "walk.bvh", "motionbuilder", angles, root, Rotation.identity(), 1.0))
    motion = retarget(clip, SKEL, 60.0)
    assert motion.n_frames == 121
    np.testing.assert_allclose(motion.joint_angles[2:-2], angles[::2][2:-2], atol=1e-3)
    # PCHIP flattens the curve at its extremes: rates there are off by a few hundredths of rad/s.
    np.testing.assert_allclose(motion.joint_angle_rates[2:-2], rates[::2][2:-2], atol=0.05)
    np.testing.assert_allclose(motion.root_velocity[2:-2, [0, 2]], np.tile([0.0, 0.5], (117, 1)), atol=1e-3)
    window = retarget(clip, SKEL, 60.0, start=0.5, end=1.5)
    assert window.n_frames == 61 and window.kind == "bvh:walk@0.5-1.5"
    # The window starts facing +z: the pelvis turns by its angle at 0.5 s less, the joints below it as before.
    np.testing.assert_allclose(window.joint_angles[:, 0, 1], angles[60:181:2, 0, 1] - angles[60, 0, 1], atol=1e-3)
    np.testing.assert_allclose(window.joint_angles[:, 1:], angles[60:181:2, 1:], atol=1e-3)
    np.testing.assert_allclose(window.root_position[0, [0, 2]], [0.0, 0.0], atol=1e-9)
    forward = Rotation.from_quat(window.joint_rotations[0, 0]).apply([0.0, 0.0, 1.0])
    assert abs(forward[0]) < 1e-3 and forward[2] > 0   # facing +z where the window starts
    for start, end in ((1.5, 0.5), (0.0, 2.5), (-0.1, 1.0)):
        with pytest.raises(ValueError, match="need fps > 0 and 0 <= start < end"):
            retarget(clip, SKEL, 60.0, start=start, end=end)


def test_angles_beyond_the_limits_are_clamped(tmp_path):
    t, angles, _ = known_motion(seed=2)
    angles = angles * 2.5   # well past every limit, knees and elbows bent backwards half of the time
    root = np.stack([np.zeros_like(t), np.full_like(t, 0.9), np.zeros_like(t)], axis=1)
    clip = read_bvh(mannequin_bvh(tmp_path / "wild.bvh", "3dsmax", angles, root, Rotation.identity(), 1.0))
    motion = retarget(clip, SKEL, 60.0)
    assert np.isfinite(motion.joint_angles).all() and np.isfinite(motion.joint_angle_rates).all()
    assert within_limits(motion)


def test_unmappable_file_names_the_missing_joints(tmp_path):
    joints = [Joint("Hips", -1, (0, 0.95, 0), has_position=True), Joint("Spine", 0, (0, 0.2, 0)),
              Joint("Head", 1, (0, 0.5, 0), end_site=(0, 0.2, 0)), Joint("LeftArm", 1, (0.2, 0.4, 0)),
              Joint("LeftForeArm", 3, (0, -0.3, 0)), Joint("LeftHand", 4, (0, -0.25, 0), end_site=(0, -0.1, 0))]
    clip = read_bvh(write_bvh(tmp_path / "torso.bvh", joints, np.zeros((2, 21))))
    with pytest.raises(ValueError) as error:
        retarget(clip, SKEL, 60.0)
    message = str(error.value)
    assert message.startswith("cannot map BVH 'torso' onto the mannequin: no joint for ") and "\n" not in message
    assert "chest (Chest2/Spine2/Thorax/Spine1/Chest/UpperBack/CC_Base_Spine02)" in message
    assert "thigh_l (LeftUpLeg/LeftUpperLeg/LeftThigh/lfemur/LeftHip/lThigh/CC_Base_L_Thigh)" in message
    missing = [part for part in SKEL.names if f" {part} (" in message]
    assert missing == ["chest", "upper_arm_r", "lower_arm_r", "hand_r", "thigh_l", "shin_l", "foot_l", "thigh_r",
                       "shin_r", "foot_r"]


def test_shared_cmu_walk():
    if not CMU_WALK.exists():
        pytest.skip(f"shared mocap clip not found at {CMU_WALK}")
    clip = read_bvh(CMU_WALK)
    assert motion_start(clip) == 0                                      # no T-pose: its first frame is motion
    motion = retarget(clip, SKEL, 60.0)
    assert motion.n_frames == int(clip.duration * 60) + 1
    assert np.isfinite(motion.joint_angles).all() and np.isfinite(motion.root_velocity).all()
    assert within_limits(motion)
    assert np.abs(lowest_foot_point(motion)).max() < 0.02            # a foot on the ground every frame
    np.testing.assert_allclose(motion.root_position[0, [0, 2]], [0.0, 0.0], atol=1e-9)
    travel = motion.root_position[-1] - motion.root_position[0]
    assert travel[2] > 2.0 and abs(travel[0]) < 0.35 * travel[2]      # walks about 2.5 m forward (+z)
    # Exact rates: they match central differences of the angles, and the root velocity that of the position.
    dt = 1 / motion.fps
    fd = (motion.joint_angles[2:] - motion.joint_angles[:-2]) / (2 * dt)
    assert np.median(np.abs(fd - motion.joint_angle_rates[1:-1])) < 0.01
    fd_root = (motion.root_position[2:] - motion.root_position[:-2]) / (2 * dt)
    assert np.median(np.abs(fd_root - motion.root_velocity[1:-1])) < 0.01


def test_rig_whose_zero_pose_is_no_standing_pose(tmp_path):
    """CC_Base's zero pose has every limb pointing up: its thighs and upper arms are laid along the source's in the
    frame of the clip closest to the mannequin's rest pose (here one at rest, so the round trip is exact), the
    joints below them and the torso in the zero pose."""
    t, angles, _ = known_motion(seed=3, rest_at=1.2)
    root = np.stack([0.05 * np.sin(OMEGA * t), np.full_like(t, 0.9), 0.6 * t], axis=1)
    clip = read_bvh(mannequin_bvh(tmp_path / "cc.bvh", "cc_base", angles, root, Rotation.identity(), UNITS["cm"]))
    rest = clip.rest_positions()
    assert rest[clip.names.index("CC_Base_L_Foot"), 1] > rest[clip.names.index("CC_Base_L_Thigh"), 1] + 0.7
    assert clip.unit_scale == UNITS["cm"] and motion_start(clip) == 0
    assert {p: clip.names[j] for p, j in joint_map(clip, SKEL).items()} == {
        p: source_name("cc_base", p) for p in SKEL.names}
    motion = retarget(clip, SKEL, FPS)
    # Near the rest frame elbows and knees straighten into their soft limits: compared away from it.
    away = (np.abs(t - 1.2) > 0.5) & (t > 0.03) & (t < t[-1] - 0.03)
    np.testing.assert_allclose(motion.joint_angles[away], angles[away], atol=5e-4)
    np.testing.assert_allclose(motion.root_position[:, [0, 2]], root[:, [0, 2]] - root[0, [0, 2]], atol=2e-3)
    # A clip that never stands: nothing to lay its limbs along.
    joints, frames = mannequin_channels("cc_base", angles[:20], root[:20], Rotation.identity(), UNITS["cm"])
    frames[:, 3:] = 0.0
    frozen = read_bvh(write_bvh(tmp_path / "frozen.bvh", joints, frames))
    with pytest.raises(ValueError, match="no frame of it comes within 90° of the mannequin's rest pose"):
        retarget(frozen, SKEL, 60.0)


def rest_frame(frames: np.ndarray) -> np.ndarray:
    """A frame of the zero pose (every rotation 0) where the clip's root starts."""
    rest = np.zeros(frames.shape[1])
    rest[:3] = frames[0, :3]
    return rest


def test_leading_rest_pose_and_its_blend_are_not_played(tmp_path):
    t, angles, _ = known_motion(seed=4)
    root = np.stack([np.zeros_like(t), np.full_like(t, 0.9), 0.4 * t], axis=1)
    joints, frames = mannequin_channels("daz", angles, root, Rotation.identity(), UNITS["cm"])
    blend = frames[0] + np.random.default_rng(0).uniform(-40, 40, (REST_LEAD_FRAMES - 1, frames.shape[1]))
    blend[:, :3] = frames[0, :3]
    led = read_bvh(write_bvh(tmp_path / "led.bvh", joints, np.concatenate([[rest_frame(frames)], blend, frames])))
    plain = read_bvh(write_bvh(tmp_path / "plain.bvh", joints, frames))
    assert motion_start(led) == REST_LEAD_FRAMES == 8 and motion_start(plain) == 0
    assert led.duration == pytest.approx(plain.duration + 8 / 120)
    for window in ({}, {"start": 0.0, "end": 0.5}, {"start": 0.7, "end": plain.duration}):
        played, expected = retarget(led, SKEL, 60.0, **window), retarget(plain, SKEL, 60.0, **window)
        assert played.n_frames == expected.n_frames
        for field in ("joint_angles", "joint_angle_rates", "root_position", "root_velocity"):
            np.testing.assert_allclose(getattr(played, field), getattr(expected, field), atol=1e-9)
    with pytest.raises(ValueError, match=r"of motion, from frame 8\)"):
        retarget(led, SKEL, 60.0, start=0.0, end=plain.duration + 0.01)


@pytest.mark.parametrize("joint, degrees, at_rest", [
    ("lThigh", 15.0, True), ("lThigh", 25.0, False),     # drives the mannequin: within REST_TOLERANCE (20°) or not
    ("lCollar", 60.0, True),                             # drives nothing (as Daz's curled fingers, 10°)
    ("hip", 90.0, True),                                 # the file's root: its heading
])
def test_frame_zero_is_a_rest_pose_within_the_tolerance(tmp_path, joint, degrees, at_rest):
    t, angles, _ = known_motion(seed=5)
    joints, frames = mannequin_channels("daz", angles, np.tile([0.0, 0.9, 0.0], (len(t), 1)), Rotation.identity(),
                                        UNITS["cm"])
    frames[0] = rest_frame(frames)
    frames[0, 3 + 3 * [j.name for j in joints].index(joint)] = degrees     # about its first rotation axis
    assert motion_start(read_bvh(write_bvh(tmp_path / "clip.bvh", joints, frames))) == (8 if at_rest else 0)


def shared_clip(folder: str, name: str):
    """A clip of a shared library at its true frame rate (the manifest's cmu_capture_fps where the header is
    wrong)."""
    row = next(row for row in manifest(folder) if row["clip"] == name)
    wrong = folder == "cmu" and row["cmu_capture_fps"] != "120"
    return read_bvh(MOCAP / folder / row["file"], frame_time=1 / float(row["cmu_capture_fps"]) if wrong else None)


def capsule_tips(motion) -> np.ndarray:
    """Far ends (F, P, 3) of every capsule relative to the pelvis's joint."""
    state = body_state(SKEL, motion)
    _, b, _, _ = capsules_world(SKEL, state.transforms)
    return b - state.translation[:, :1]


def test_shared_daz_walk_looks_like_a_walk():
    clip = shared_clip("cmu", "05_01")       # "walk", Daz/Poser names, a T-pose at frame 0
    assert motion_start(clip) == 8
    motion = retarget(clip, SKEL, 60.0)
    assert np.isfinite(motion.joint_angles).all() and within_limits(motion)
    state = body_state(SKEL, motion)
    _, tips, _, _ = capsules_world(SKEL, state.transforms)
    # The T-pose is not played: the hands hang well below the shoulders from the first frame on.
    shoulders = state.translation[:, [SKEL.index("upper_arm_l"), SKEL.index("upper_arm_r")], 1]
    hands = tips[:, [SKEL.index("hand_l"), SKEL.index("hand_r")], 1]
    assert (shoulders - hands).min() > 0.3
    # The pelvis travels forward (+z) about 4 m, nearly straight, with a foot on the ground every frame.
    travel = motion.root_position[-1] - motion.root_position[0]
    assert 3.5 < travel[2] < 5.0 and abs(travel[0]) < 0.1 * travel[2]
    assert np.abs(lowest_foot_point(motion)).max() < 0.02
    # The feet take turns in front, by more than 40 cm each, about two steps a second.
    lead = tips[:, SKEL.index("foot_l"), 2] - tips[:, SKEL.index("foot_r"), 2]
    steps = np.count_nonzero(np.diff(np.sign(lead)))
    assert lead.max() > 0.4 and lead.min() < -0.4 and 1.0 < steps / (motion.n_frames / 60.0) < 2.5
    # The head stays above the pelvis.
    head = state.translation[:, SKEL.index("head"), 1] - state.translation[:, 0, 1]
    assert head.min() > 0.4


def test_shared_clip_on_two_rigs_agrees():
    """CMU trial 03_01 (a walk) converted to Daz/Poser names (120 fps, a T-pose first) and retargeted by Reallusion
    onto CC_Base (60 fps, limbs up in its zero pose) plays the same motion on the mannequin."""
    daz, cc = (retarget(shared_clip(folder, "03_01"), SKEL, 60.0) for folder in ("cmu", "cmu_rigs"))
    daz_tips, cc_tips = capsule_tips(daz), capsule_tips(cc)
    n = min(len(daz_tips), len(cc_tips)) - 10

    def gap(shift: int) -> np.ndarray:
        """Distance (F, P) between the two motions' capsule tips, the CC one `shift` frames later."""
        return np.linalg.norm(daz_tips[5:5 + n] - cc_tips[5 + shift:5 + shift + n], axis=2)

    shift = min(range(-5, 6), key=lambda shift: np.median(gap(shift)))   # the two start a frame or so apart
    distance = gap(shift)
    # Measured: head 7 cm, feet 8-10 cm, hands 13-23 cm (the Daz/Poser forearms are bent 17° more at rest).
    for part, limit in (("head", 0.1), ("foot_l", 0.15), ("foot_r", 0.15), ("hand_l", 0.3), ("hand_r", 0.3)):
        assert np.median(distance[:, SKEL.index(part)]) < limit, part
    daz_angles, cc_angles = daz.joint_angles[5:5 + n], cc.joint_angles[5 + shift:5 + shift + n]
    for part in ("shin_l", "shin_r", "thigh_l", "thigh_r"):
        p = SKEL.index(part)
        assert np.corrcoef(daz_angles[:, p, 0], cc_angles[:, p, 0])[0, 1] > 0.8, part      # flexion: 0.86-0.96
    # The thighs' twist: 3 and 5° RMS apart (18 and 11° where CC_Base's thighs are laid along its zero pose, up).
    for part in ("thigh_l", "thigh_r"):
        twist = daz_angles[:, SKEL.index(part), 1] - cc_angles[:, SKEL.index(part), 1]
        assert np.degrees(np.sqrt(np.mean(twist ** 2))) < 8, part


def test_shared_library_sample_retargets():
    """A clip of every subject of the shared library and every clip on the CC_Base rig: read at the true frame
    rate, mapped, T-pose dropped where there is one, and retargeted from the first frame of motion and in the
    middle, finite and within the limits."""
    clips = {}
    for row in manifest("cmu"):
        clips.setdefault(row["subject"], ("cmu", row["clip"]))
    clips.update({f"rig {row['clip']}": ("cmu_rigs", row["clip"]) for row in manifest("cmu_rigs")})
    assert len(clips) == 15 + 4
    for folder, name in clips.values():
        clip = shared_clip(folder, name)
        assert motion_start(clip) == {"cmu": 8, "cmu_rigs": 0}[folder], name
        seconds = clip.duration - motion_start(clip) * clip.frame_time
        window = min(2.0, seconds)
        for start in (0.0, 0.5 * (seconds - window)):
            motion = retarget(clip, SKEL, 60.0, start, start + window)
            assert np.isfinite(motion.joint_angles).all() and within_limits(motion), name
