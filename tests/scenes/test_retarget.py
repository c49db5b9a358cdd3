"""Retargeting BVH onto the mannequin: a round trip through known joint angles written as BVH files in two CMU
naming conventions, Y-up and Z-up, several units and every rotation order; resampling and windows; limits; a
clear error for an unmappable file; and the shared CMU walk (skipped where ../shared/mocap is absent)."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bvh_files import Joint, write_bvh
from scenes.bvh import UNITS, read_bvh
from scenes.capsules import capsules_world
from scenes.kinematics import forward_kinematics, joint_quaternions, rest_transforms
from scenes.motion import body_state
from scenes.retarget import joint_map, retarget
from scenes.skeleton import default_skeleton

SKEL = default_skeleton()
CMU_WALK = Path(__file__).resolve().parents[3] / "shared" / "mocap" / "cmu_131_01_walk.bvh"
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
# Joint names per mannequin part in two of CMU's releases, and the collar joint each puts before the upper arm.
CONVENTIONS = {
    "motionbuilder": {"pelvis": "Hips", "spine": "Spine", "chest": "Spine1", "head": "Head", "collar": "{Side}Shoulder",
                      "upper_arm": "{Side}Arm", "lower_arm": "{Side}ForeArm", "hand": "{Side}Hand",
                      "thigh": "{Side}UpLeg", "shin": "{Side}Leg", "foot": "{Side}Foot"},
    "3dsmax": {"pelvis": "Hips", "spine": "lowerback", "chest": "Chest2", "head": "Head", "collar": "{Side}Collar",
               "upper_arm": "{Side}Shoulder", "lower_arm": "{Side}Elbow", "hand": "{Side}Wrist",
               "thigh": "{Side}Hip", "shin": "{Side}Knee", "foot": "{Side}Ankle"},
}
FPS, SECONDS, OMEGA = 120.0, 2.0, 2 * np.pi * 0.4


def source_name(convention: str, part: str) -> str:
    base, side = (part[:-2], part[-2:]) if part[-2:] in ("_l", "_r") else (part, "")
    return CONVENTIONS[convention][base].format(Side={"_l": "Left", "_r": "Right", "": ""}[side])


def known_motion(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (T,), joint angles (T, P, 3) and their rates: sinusoids inside the limits (shrunk by 10% of each
    range, with |x| <= 60° for joints that also lean, away from gimbal lock); the pelvis starts at rest."""
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
    return t, mid + amplitude * np.sin(arg), amplitude * OMEGA * np.cos(arg)


def mannequin_bvh(path: Path, convention: str, angles: np.ndarray, root: np.ndarray, axes: Rotation,
                  unit: float) -> Path:
    """A BVH file of the mannequin's rest skeleton playing `angles` (T, P, 3) with the pelvis at `root` (T, 3),
    in the file axes `axes` (a rotation from the mannequin's) and `unit` metres per unit. Each joint's world
    rotation is the mannequin part's relative to its rest; collars sit between chest and upper arms."""
    rest_rotation, rest_position = rest_transforms(SKEL)
    rotation, _ = forward_kinematics(SKEL, root, joint_quaternions(angles))
    world = [axes * Rotation.from_quat(rotation[:, p]) * Rotation.from_quat(rest_rotation[p]).inv() * axes.inv()
             for p in range(SKEL.n_parts)]
    joints, local, index = [], [], {}
    for p, (part, parent) in enumerate(zip(SKEL.names, SKEL.parents)):
        source_parent = -1 if parent < 0 else index[SKEL.names[parent]]
        if part.startswith("upper_arm"):
            joints.append(Joint(source_name(convention, "collar" + part[-2:]), source_parent, (0, 0, 0),
                                ORDERS[len(joints) % 6]))
            local.append(Rotation.identity(len(root)))
            source_parent = len(joints) - 1
        offset = rest_position[p] - (0 if parent < 0 else rest_position[parent])
        end = None
        if part.split("_")[0] in ("head", "hand", "foot"):
            end = tuple(axes.apply(Rotation.from_quat(rest_rotation[p]).apply(SKEL.capsule_b[p])) / unit)
        index[part] = len(joints)
        joints.append(Joint(source_name(convention, part), source_parent, tuple(axes.apply(offset) / unit),
                            ORDERS[len(joints) % 6], has_position=parent < 0, end_site=end))
        local.append(world[p] if parent < 0 else world[parent].inv() * world[p])
    columns = [axes.apply(root) / unit]
    columns += [r.as_euler(j.rotation_order, degrees=True) for j, r in zip(joints, local)]
    return write_bvh(path, joints, np.concatenate(columns, axis=1), 1 / FPS)


def within_limits(motion) -> bool:
    angles = motion.joint_angles
    return bool(((angles >= SKEL.joint_lower - 1e-9) & (angles <= SKEL.joint_upper + 1e-9)).all())


def lowest_foot_point(motion) -> np.ndarray:
    """Height (F,) of the lowest point of the two foot capsules."""
    a, b, ra, rb = capsules_world(SKEL, body_state(SKEL, motion).transforms)
    feet = [SKEL.index("foot_l"), SKEL.index("foot_r")]
    return np.minimum(a[:, feet, 1] - ra[:, feet], b[:, feet, 1] - rb[:, feet]).min(axis=1)


@pytest.mark.parametrize("convention, axes, unit", [
    ("motionbuilder", Rotation.identity(), "m"),
    ("3dsmax", Rotation.from_euler("ZX", [70, 90], degrees=True), "cm"),   # Z-up, facing turned by 70°
    ("3dsmax", Rotation.identity(), "CMU ASF unit"),
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
