"""Mannequin geometry and kinematics: the skeleton's layout, forward kinematics against poses worked out by hand,
velocities against finite differences, capsule distances against a brute-force union of spheres, and the render
mesh against trimesh."""
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from geometry.rotations import quat_canonical, quat_rotate
from scenes.body_mesh import body_mesh
from scenes.capsules import (capsule_pair_clearance, capsule_signed_distance, capsule_velocities, capsules_world,
                             segment_closest_parameters, self_collision_pairs)
from scenes.kinematics import (forward_kinematics, joint_angular_velocity, joint_quaternions, part_velocities,
                               rest_transforms)
from scenes.skeleton import Skeleton, default_skeleton

SKEL = default_skeleton()
IDENTITY = np.tile([0.0, 0.0, 0.0, 1.0], (SKEL.n_parts, 1))


def pose(**angles_deg):
    """Joint quaternions (P, 4) with the given parts' (x, y, z) joint angles in degrees, others at rest."""
    angles = np.zeros((SKEL.n_parts, 3))
    for name, values in angles_deg.items():
        angles[SKEL.index(name)] = np.radians(values)
    return joint_quaternions(angles)


def test_joint_angles_compose_as_z_x_y():
    angles = np.random.default_rng(3).uniform(-2, 2, size=(20, 3))
    expected = Rotation.from_euler("ZXY", angles[:, [2, 0, 1]]).as_quat()      # intrinsic: Rz Rx Ry
    np.testing.assert_allclose(quat_canonical(joint_quaternions(angles)), quat_canonical(expected), atol=1e-12)


def test_joint_angular_velocity_matches_finite_differences():
    rng = np.random.default_rng(4)
    angles, rates, h = rng.uniform(-1.5, 1.5, (10, 3)), rng.normal(size=(10, 3)), 1e-6
    r_plus = Rotation.from_quat(joint_quaternions(angles + h * rates))
    r_minus = Rotation.from_quat(joint_quaternions(angles - h * rates))
    numeric = (r_plus * r_minus.inv()).as_rotvec() / (2 * h)                   # spatial angular velocity
    np.testing.assert_allclose(joint_angular_velocity(angles, rates), numeric, atol=1e-6)


def test_default_skeleton_layout_and_size():
    assert SKEL.n_parts == 16
    assert SKEL.parents[0] == -1 and all(SKEL.parents[p] < p for p in range(1, 16))
    for height in (1.7, 1.2, 2.0):
        skel = default_skeleton(height)
        a, b, ra, rb = capsules_world(skel, rest_transforms(skel))
        bottom = np.minimum(a[:, 1] - ra, b[:, 1] - rb)
        top = np.maximum(a[:, 1] + ra, b[:, 1] + rb)
        assert bottom.min() == pytest.approx(0.0, abs=1e-12)                   # feet on the ground
        assert top.max() == pytest.approx(height, rel=1e-9)
    # Left/right twins mirror each other through x = 0; feet point forward (+z).
    a, b, _, _ = capsules_world(SKEL, rest_transforms(SKEL))
    for left in [n for n in SKEL.names if n.endswith("_l")]:
        i, j = SKEL.index(left), SKEL.index(left[:-2] + "_r")
        np.testing.assert_allclose(a[i] * [-1, 1, 1], a[j], atol=1e-12)
        np.testing.assert_allclose(b[i] * [-1, 1, 1], b[j], atol=1e-12)
        assert a[i, 0] > 0
    foot = SKEL.index("foot_l")
    assert b[foot, 2] > a[foot, 2]


def test_rest_pose_lies_within_limits_and_mirrors_limits():
    assert (SKEL.joint_lower <= 0).all() and (SKEL.joint_upper >= 0).all()
    i, j = SKEL.index("thigh_l"), SKEL.index("thigh_r")
    np.testing.assert_allclose(SKEL.joint_lower[j], [SKEL.joint_lower[i, 0], *-SKEL.joint_upper[i, 1:]])


def test_elbow_bent_90_degrees_puts_the_wrist_in_front_of_the_elbow():
    # By hand: the left upper arm hangs 45° out from the shoulder (0.18, 1.39, 0) and is 0.29 long; flexing the
    # elbow by -90° about the arm's hinge axis swings the 0.25 long forearm to point straight forward (+z).
    rotation, translation = forward_kinematics(SKEL, SKEL.joint_offsets[0], pose(lower_arm_l=(-90, 0, 0)))
    s45 = np.sqrt(0.5)
    elbow = np.array([0.18 + 0.29 * s45, 1.39 - 0.29 * s45, 0.0])
    np.testing.assert_allclose(translation[SKEL.index("lower_arm_l")], elbow, atol=1e-12)
    np.testing.assert_allclose(translation[SKEL.index("hand_l")], elbow + [0, 0, 0.25], atol=1e-12)
    # The hand's frame turned with the forearm: its local -y now points along +z.
    np.testing.assert_allclose(quat_rotate(rotation[SKEL.index("hand_l")], [0, -1, 0]), [0, 0, 1], atol=1e-12)


def test_hip_flexion_and_root_motion_by_hand():
    # Thigh flexed -90°: the knee comes forward to hip + (0, 0, 0.41); the shin, unbent, hangs forward too.
    _, t = forward_kinematics(SKEL, SKEL.joint_offsets[0], pose(thigh_r=(-90, 0, 0)))
    hip = np.array([-0.1, 0.9, 0.0])
    np.testing.assert_allclose(t[SKEL.index("shin_r")], hip + [0, 0, 0.41], atol=1e-12)
    np.testing.assert_allclose(t[SKEL.index("foot_r")], hip + [0, 0, 0.81], atol=1e-12)
    # Turning the root by +90° about y and moving it: the left hip (+x at rest) goes to -z of the new root.
    root = np.array([1.0, 0.95, 2.0])
    _, t = forward_kinematics(SKEL, root, pose(pelvis=(0, 90, 0)))
    np.testing.assert_allclose(t[SKEL.index("thigh_l")], root + [0.0, -0.05, -0.1], atol=1e-12)


def test_forward_kinematics_broadcasts_over_frames_and_checks_shapes():
    rng = np.random.default_rng(5)
    angles = rng.uniform(-0.5, 0.5, (7, SKEL.n_parts, 3))
    roots = rng.normal(size=(7, 3))
    rotation, translation = forward_kinematics(SKEL, roots, joint_quaternions(angles))
    for f in (0, 6):
        r, t = forward_kinematics(SKEL, roots[f], joint_quaternions(angles[f]))
        np.testing.assert_allclose(rotation[f], r, atol=1e-14)
        np.testing.assert_allclose(translation[f], t, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(rotation, axis=-1), 1.0, atol=1e-12)
    with pytest.raises(ValueError, match="joint_rotations"):
        forward_kinematics(SKEL, roots[0], np.zeros((SKEL.n_parts - 1, 4)))


def test_part_and_capsule_velocities_match_finite_differences():
    rng = np.random.default_rng(6)
    angles, rates = rng.uniform(-0.6, 0.6, (SKEL.n_parts, 3)), rng.normal(size=(SKEL.n_parts, 3))
    root, root_velocity, h = np.array([0.1, 0.9, -0.2]), rng.normal(size=3), 1e-6

    def at(dt):
        return forward_kinematics(SKEL, root + dt * root_velocity, joint_quaternions(angles + dt * rates))

    rotation, translation = at(0.0)
    linear, angular = part_velocities(SKEL, rotation, joint_angular_velocity(angles, rates), root_velocity)
    (r_plus, t_plus), (r_minus, t_minus) = at(h), at(-h)
    np.testing.assert_allclose(linear, (t_plus - t_minus) / (2 * h), atol=1e-6)
    spin = (Rotation.from_quat(r_plus) * Rotation.from_quat(r_minus).inv()).as_rotvec() / (2 * h)
    np.testing.assert_allclose(angular, spin, atol=1e-6)
    va, vb = capsule_velocities(SKEL, (rotation, translation), (linear, angular))
    a_plus, b_plus, _, _ = capsules_world(SKEL, (r_plus, t_plus))
    a_minus, b_minus, _, _ = capsules_world(SKEL, (r_minus, t_minus))
    np.testing.assert_allclose(va, (a_plus - a_minus) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(vb, (b_plus - b_minus) / (2 * h), atol=1e-6)


def sphere_union_distance(points, a, b, ra, rb, samples=4001):
    """Reference: a tapered capsule is the union of the spheres interpolated between its end spheres."""
    t = np.linspace(0.0, 1.0, samples)
    centers = a + t[:, None] * (b - a)
    radii = ra + t * (rb - ra)
    return (np.linalg.norm(points[:, None] - centers[None], axis=-1) - radii).min(axis=1)


@pytest.mark.parametrize("ra, rb", [(0.1, 0.1), (0.12, 0.05), (0.03, 0.09)])
def test_capsule_distance_matches_union_of_spheres(ra, rb):
    a, b = np.array([0.2, -0.1, 0.3]), np.array([-0.1, 0.4, 0.25])
    rng = np.random.default_rng(7)
    offsets = rng.normal(size=(400, 3))
    offsets *= rng.uniform(0.0, 0.3, (400, 1)) / np.linalg.norm(offsets, axis=1, keepdims=True)
    points = a + rng.uniform(-0.3, 1.3, (400, 1)) * (b - a) + offsets
    distance = capsule_signed_distance(points, a[None], b[None], np.array([ra]), np.array([rb]))[:, 0]
    reference = sphere_union_distance(points, a, b, ra, rb)
    outside = reference > 0
    assert outside.sum() > 200 and (~outside).sum() > 20
    np.testing.assert_allclose(distance[outside], reference[outside], atol=1e-6)
    assert (distance[~outside] <= 0).all()
    # Deep inside, on the axis, the distance is minus the largest inscribed sphere's radius there at least.
    mid = 0.5 * (a + b)
    assert capsule_signed_distance(mid[None], a[None], b[None], np.array([ra]), np.array([rb]))[0, 0] \
        <= -min(ra, rb) + 1e-12


def test_segment_closest_parameters_match_brute_force():
    rng = np.random.default_rng(8)
    p0, p1, q0, q1 = rng.normal(size=(4, 60, 3))
    q1[:10] = q0[:10] + 2.0 * (p1[:10] - p0[:10])                                # parallel pairs
    s, t = segment_closest_parameters(p0, p1, q0, q1)
    grid = np.linspace(0, 1, 201)
    pp = p0[:, None] + grid[None, :, None] * (p1 - p0)[:, None]
    qq = q0[:, None] + grid[None, :, None] * (q1 - q0)[:, None]
    brute = np.linalg.norm(pp[:, :, None] - qq[:, None, :], axis=-1).min(axis=(1, 2))
    found = np.linalg.norm(p0 + s[:, None] * (p1 - p0) - q0 - t[:, None] * (q1 - q0), axis=1)
    assert ((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)).all()
    assert (found <= brute + 1e-9).all() and np.allclose(found, brute, atol=5e-3)


def test_self_collision_pairs_skip_joined_parts_and_detect_crossed_legs():
    pairs = {tuple(p) for p in self_collision_pairs(SKEL)}
    names = lambda a, b: tuple(sorted((SKEL.index(a), SKEL.index(b))))   # noqa: E731
    assert names("thigh_l", "pelvis") not in pairs and names("shin_l", "thigh_l") not in pairs
    assert names("thigh_l", "thigh_r") in pairs and names("lower_arm_l", "chest") in pairs
    pair_array = np.array(sorted(pairs))
    assert (capsule_pair_clearance(SKEL, rest_transforms(SKEL), pair_array) > 0.02).all()
    # Both legs swung 20° inward cross at the shins.
    crossed = forward_kinematics(SKEL, SKEL.joint_offsets[0], pose(thigh_l=(0, 0, -20), thigh_r=(0, 0, 20)))
    gap = capsule_pair_clearance(SKEL, crossed, np.array([names("shin_l", "shin_r")]))
    assert gap[0] < 0


def test_body_mesh_is_watertight_outward_and_on_the_capsules():
    transforms = forward_kinematics(SKEL, [0.3, 1.0, -0.2], pose(lower_arm_l=(-90, 0, 0), thigh_r=(-60, 10, 5)))
    vertices, faces = body_mesh(SKEL, transforms, segments=12)
    a, b, ra, rb = capsules_world(SKEL, transforms)
    per_part, faces_per_part = len(vertices) // SKEL.n_parts, len(faces) // SKEL.n_parts
    for p in range(SKEL.n_parts):
        part = trimesh.Trimesh(vertices[p * per_part:(p + 1) * per_part],
                               faces[p * faces_per_part:(p + 1) * faces_per_part] - p * per_part, process=False)
        assert part.is_watertight and part.is_winding_consistent and part.volume > 0, SKEL.names[p]
        gap = capsule_signed_distance(part.vertices, a[p:p + 1], b[p:p + 1], ra[p:p + 1], rb[p:p + 1])
        assert np.abs(gap).max() < 1e-12


def test_body_mesh_volume_converges_to_the_capsule_volume():
    skel = Skeleton(names=("rod",), parents=np.array([-1]), joint_offsets=np.zeros((1, 3)),
                    frame_rotations=np.array([[0.0, 0, 0, 1]]), capsule_a=np.array([[0.0, 0, 0]]),
                    capsule_b=np.array([[0.0, 0.5, 0]]), radius_a=np.array([0.1]), radius_b=np.array([0.1]),
                    joint_lower=np.zeros((1, 3)), joint_upper=np.zeros((1, 3)), height=0.7)
    vertices, faces = body_mesh(skel, rest_transforms(skel), segments=96)
    exact = np.pi * 0.1 ** 2 * 0.5 + 4 / 3 * np.pi * 0.1 ** 3
    assert trimesh.Trimesh(vertices, faces).volume == pytest.approx(exact, rel=2e-3)


def test_skeleton_rejects_inconsistent_fields():
    fields = {k: getattr(SKEL, k) for k in SKEL.__dataclass_fields__}
    with pytest.raises(ValueError, match="parents"):
        Skeleton(**{**fields, "parents": np.r_[-1, 2, SKEL.parents[2:]]})
    with pytest.raises(ValueError, match="radii"):
        Skeleton(**{**fields, "radius_a": -SKEL.radius_a})
    with pytest.raises(ValueError, match="rest pose"):
        Skeleton(**{**fields, "joint_lower": SKEL.joint_lower + 1.0})
    with pytest.raises(ValueError, match="no body part 'tail'"):
        SKEL.index("tail")
