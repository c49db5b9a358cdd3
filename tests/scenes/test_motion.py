"""Procedural motions: limits, settle period, smoothness (finite-difference accelerations), exact velocities
against finite differences at a high frame rate, determinism, plausibility, and the pose vector's layout."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scenes.capsules import capsule_pair_clearance, capsules_world, self_collision_pairs
from scenes.kinematics import forward_kinematics, rest_transforms
from scenes.skeleton import default_skeleton
from scenes.motion import MOTION_KINDS, body_state, make_motion, pose_vectors, soft_limit

SKEL = default_skeleton()
MOVING = [k for k in MOTION_KINDS if k != "rest"]
FPS, FRAMES, SETTLE, BLEND = 60.0, 480, 30, 40


@pytest.fixture(scope="module")
def motions():
    return {kind: make_motion(kind, FRAMES, FPS, seed=2, settle_frames=SETTLE, blend_frames=BLEND, skel=SKEL)
            for kind in MOTION_KINDS}


@pytest.fixture(scope="module")
def fine_motions():
    """Motions sampled at 2400 fps over 2.5 s, for finite-difference checks of derivatives. (Keyframed motions
    are C¹: their second derivative jumps at keyframes, where central differences err by O(jump / fps).)"""
    fps = 2400.0
    return fps, {kind: make_motion(kind, 6000, fps, seed=5, settle_frames=240, blend_frames=1200, skel=SKEL)
                 for kind in MOVING}


@pytest.mark.parametrize("kind", MOTION_KINDS)
def test_shapes_limits_and_unit_quaternions(motions, kind):
    m = motions[kind]
    assert m.root_position.shape == (FRAMES, 3) and m.joint_angles.shape == (FRAMES, SKEL.n_parts, 3)
    assert np.isfinite(m.joint_angles).all() and np.isfinite(m.root_velocity).all()
    assert (m.joint_angles >= SKEL.joint_lower - 1e-12).all() and (m.joint_angles <= SKEL.joint_upper + 1e-12).all()
    np.testing.assert_allclose(np.linalg.norm(m.joint_rotations, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("kind", MOTION_KINDS)
def test_settle_frames_hold_the_rest_pose(motions, kind):
    m = motions[kind]
    still = slice(0, SETTLE + 1)
    assert np.abs(m.joint_angles[still]).max() == 0.0 and np.abs(m.joint_angle_rates[still]).max() == 0.0
    np.testing.assert_allclose(m.root_position[still], np.broadcast_to(SKEL.joint_offsets[0], (SETTLE + 1, 3)),
                               atol=1e-9)
    np.testing.assert_allclose(m.root_velocity[still], 0.0, atol=1e-8)


def test_rest_motion_never_moves(motions):
    m = motions["rest"]
    assert np.abs(m.joint_angles).max() == 0.0
    np.testing.assert_allclose(m.root_position, np.broadcast_to(SKEL.joint_offsets[0], (FRAMES, 3)), atol=1e-12)


@pytest.mark.parametrize("kind", MOVING)
def test_motion_is_smooth_with_bounded_acceleration(motions, kind):
    m, dt = motions[kind], 1.0 / FPS
    state = body_state(SKEL, m)
    part_acceleration = np.linalg.norm(np.diff(state.translation, 2, axis=0), axis=-1) / dt ** 2
    joint_acceleration = np.abs(np.diff(m.joint_angles, 2, axis=0)) / dt ** 2
    # Bounds of brisk human motion (a karate kick reaches ~200 m/s² at the foot) catch any jump or kink.
    assert part_acceleration.max() < 250.0
    assert joint_acceleration.max() < 600.0
    assert np.linalg.norm(np.diff(m.root_position, 2, axis=0), axis=-1).max() / dt ** 2 < 20.0
    # No jump when the motion starts: velocity builds up from zero over the blend.
    velocity = np.diff(state.translation, axis=0) / dt
    assert np.abs(velocity[:SETTLE]).max() == 0.0
    assert np.abs(velocity[SETTLE]).max() < 0.01
    assert np.abs(velocity[SETTLE:SETTLE + BLEND]).max() > 0.1


@pytest.mark.parametrize("kind", MOVING)
def test_velocities_are_the_derivatives_of_the_positions(fine_motions, kind):
    fps, motions = fine_motions
    m = motions[kind]
    state = body_state(SKEL, m)
    central = lambda x: (x[2:] - x[:-2]) * fps / 2                   # noqa: E731
    np.testing.assert_allclose(m.root_velocity[1:-1], central(m.root_position), atol=2e-3)
    # A kink would leave errors of the order of the rates (several rad/s); these bounds are 50x smaller.
    np.testing.assert_allclose(m.joint_angle_rates[1:-1], central(m.joint_angles), atol=0.1)
    np.testing.assert_allclose(state.linear_velocity[1:-1], central(state.translation), atol=0.02)
    r = Rotation.from_quat(state.rotation.reshape(-1, 4))
    rotations = r.as_matrix().reshape(m.n_frames, SKEL.n_parts, 3, 3)
    relative = np.einsum("fpij,fpkj->fpik", rotations[2:], rotations[:-2])
    spin = Rotation.from_matrix(relative.reshape(-1, 3, 3)).as_rotvec().reshape(m.n_frames - 2, SKEL.n_parts, 3)
    np.testing.assert_allclose(state.angular_velocity[1:-1], spin * fps / 2, atol=0.1)


@pytest.mark.parametrize("kind", MOVING)
def test_seeded_motions_are_deterministic_and_seeds_differ(kind):
    a = make_motion(kind, 200, seed=11, settle_frames=10, blend_frames=20, skel=SKEL)
    b = make_motion(kind, 200, seed=11, settle_frames=10, blend_frames=20, skel=SKEL)
    c = make_motion(kind, 200, seed=12, settle_frames=10, blend_frames=20, skel=SKEL)
    np.testing.assert_array_equal(a.joint_angles, b.joint_angles)
    np.testing.assert_array_equal(a.root_position, b.root_position)
    assert np.abs(a.joint_angles - c.joint_angles).max() > 0.05


def test_walk_moves_forward_with_feet_on_the_ground(motions):
    m = motions["walk"]
    state = body_state(SKEL, m)
    seconds = (FRAMES - SETTLE - BLEND) / FPS
    speed = (m.root_position[-1, 2] - m.root_position[SETTLE + BLEND, 2]) / seconds
    assert 0.8 < speed < 1.6
    a, b, ra, rb = capsules_world(SKEL, state.transforms)
    feet = [SKEL.index("foot_l"), SKEL.index("foot_r")]
    lowest = np.minimum(a[:, feet, 1] - ra[:, feet], b[:, feet, 1] - rb[:, feet]).min(axis=1)
    assert np.abs(lowest).max() < 0.02                                 # always standing on y = 0, within 2 cm
    left, right = (np.minimum(a[:, p, 1] - ra[:, p], b[:, p, 1] - rb[:, p]) for p in feet)
    assert left.max() > 0.05 and right.max() > 0.05                    # each foot lifts in its swing


@pytest.mark.parametrize("kind", MOVING)
def test_limbs_do_not_pass_through_the_body(kind):
    pairs = self_collision_pairs(SKEL)
    for seed in range(3):
        m = make_motion(kind, 360, seed=seed, settle_frames=0, blend_frames=30, skel=SKEL)
        gap = capsule_pair_clearance(SKEL, body_state(SKEL, m).transforms, pairs)
        assert gap.min() > -0.01, (seed, pairs[np.unravel_index(gap.argmin(), gap.shape)[1]])


def test_pose_vector_layout_against_an_independent_computation(motions):
    m = motions["dance"]
    vectors = pose_vectors(SKEL, m)
    assert vectors.shape == (FRAMES, 13 * SKEL.n_parts) == (FRAMES, 208)
    per_part = vectors.reshape(FRAMES, SKEL.n_parts, 13)
    state = body_state(SKEL, m)
    torso = Rotation.from_quat(state.rotation[:, 0])
    for p in (0, SKEL.index("head"), SKEL.index("hand_r")):
        part = Rotation.from_quat(state.rotation[:, p])
        np.testing.assert_allclose(per_part[:, p, 0:3], torso.inv().apply(state.translation[:, p]
                                                                           - state.translation[:, 0]), atol=1e-12)
        expected = (torso.inv() * part).as_quat(canonical=True)
        np.testing.assert_allclose(per_part[:, p, 3:7], expected, atol=1e-12)
        np.testing.assert_allclose(per_part[:, p, 7:10], torso.inv().apply(state.linear_velocity[:, p]), atol=1e-12)
        np.testing.assert_allclose(per_part[:, p, 10:13], torso.inv().apply(state.angular_velocity[:, p]),
                                   atol=1e-12)
    np.testing.assert_allclose(per_part[:, 0, 0:7], np.broadcast_to([0, 0, 0, 0, 0, 0, 1.0], (FRAMES, 7)),
                               atol=1e-12)
    assert (per_part[:, :, 6] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(per_part[:, :, 3:7], axis=-1), 1.0, atol=1e-12)


def test_pose_vector_velocities_follow_finite_differences(fine_motions):
    fps, motions = fine_motions
    m = motions["karate"]
    state = body_state(SKEL, m)
    vectors = pose_vectors(SKEL, m).reshape(m.n_frames, SKEL.n_parts, 13)
    torso = Rotation.from_quat(state.rotation[1:-1, 0])
    world_velocity = (state.translation[2:] - state.translation[:-2]) * fps / 2
    for p in range(SKEL.n_parts):
        np.testing.assert_allclose(vectors[1:-1, p, 7:10], torso.inv().apply(world_velocity[:, p]), atol=0.03)


def test_pose_vectors_ignore_where_the_body_stands(motions):
    m = motions["walk"]
    moved = type(m)(**{**m.__dict__, "root_position": m.root_position + [3.0, 0.5, -2.0]})
    np.testing.assert_allclose(pose_vectors(SKEL, moved), pose_vectors(SKEL, m), atol=1e-12)


def test_rest_pose_vector_is_the_rest_skeleton(motions):
    vectors = pose_vectors(SKEL, motions["rest"]).reshape(FRAMES, SKEL.n_parts, 13)
    rotation, translation = rest_transforms(SKEL)
    np.testing.assert_allclose(vectors[:, :, 0:3], np.broadcast_to(translation - translation[0], (FRAMES, 16, 3)),
                               atol=1e-12)
    np.testing.assert_allclose(vectors[:, :, 7:], 0.0, atol=1e-12)


def test_soft_limit_is_identity_inside_and_smooth_at_the_limits():
    lower, upper = np.array([-1.0, 0.0]), np.array([2.0, 0.0])          # second DOF: empty range
    x = np.linspace(-4, 5, 9001)[:, None] * np.ones(2)
    value, rate = soft_limit(x, np.ones_like(x), lower, upper)
    assert (value[:, 0] >= -1.0).all() and (value[:, 0] <= 2.0).all() and (value[:, 1] == 0).all()
    inside = (x[:, 0] > -1.0 + 0.15) & (x[:, 0] < 2.0 - 0.15)
    np.testing.assert_array_equal(value[inside, 0], x[inside, 0])
    np.testing.assert_allclose(rate[1:-1, 0], (value[2:, 0] - value[:-2, 0]) / (2 * 0.001), atol=1e-4)
    assert np.abs(np.diff(rate[:, 0])).max() < 0.01                     # the slope has no jump


def test_invalid_arguments_are_named():
    with pytest.raises(ValueError, match="unknown motion kind 'moonwalk'"):
        make_motion("moonwalk", 10)
    with pytest.raises(ValueError, match="blend_frames >= 1"):
        make_motion("walk", 10, blend_frames=0)


def test_fk_of_motion_frames_matches_body_state(motions):
    m = motions["random"]
    rotation, translation = forward_kinematics(SKEL, m.root_position, m.joint_rotations)
    state = body_state(SKEL, m)
    np.testing.assert_array_equal(rotation, state.rotation)
    np.testing.assert_array_equal(translation, state.translation)


def test_play_clips_joins_rest_to_rest_and_stays_c1():
    from scenes.motion import play_clips
    fps, blend = 60.0, 20
    seq = play_clips(["dance", "karate", "walk"], 210, 30, blend, seed=3, fps=fps)
    m = seq.motion
    assert m.n_frames == 210 and seq.names == ("settle", "dance", "karate", "walk")
    assert np.array_equal(np.bincount(seq.clip), [30, 60, 60, 60])
    starts = np.flatnonzero(np.diff(seq.clip)) + 1
    for s in starts:   # every seam is at rest, with zero joint rates: C1 across clips
        assert np.abs(m.joint_angles[s - 1]).max() < 1e-9 and np.abs(m.joint_angle_rates[s - 1]).max() < 1e-9
        assert np.abs(m.joint_angles[s]).max() < 1e-9
    # rates are the derivative of the angles (trapezoid rule, 1/60 s steps: a few % of the largest rate)
    fd = np.diff(m.joint_angles, axis=0) * fps
    mid = 0.5 * (m.joint_angle_rates[1:] + m.joint_angle_rates[:-1])
    assert np.abs(fd - mid).max() < 0.03 * np.abs(m.joint_angle_rates).max()
    fd_root = np.diff(m.root_position, axis=0) * fps
    assert np.abs(fd_root - 0.5 * (m.root_velocity[1:] + m.root_velocity[:-1])).max() < 0.02
    # the walk travels; the clip before it ended where the walk starts (no jump)
    assert np.linalg.norm(np.diff(m.root_position, axis=0), axis=1).max() < 2.0 / fps
    assert m.root_position[-1, 2] - m.root_position[starts[-1], 2] > 0.3


def test_play_clips_refuses_clips_too_short_to_blend():
    from scenes.motion import play_clips
    with pytest.raises(ValueError, match="each needs more than"):
        play_clips(["dance", "walk"], 100, 40, 20, seed=0)


@pytest.mark.parametrize("kind", MOVING)
def test_clip_speed_amplitude_and_phase_rescale_the_raw_curves(kind):
    """clip_curves(speed s, amplitude a, phase p) at tau is a * (the plain curves at s tau + p), rates times a s,
    with amplitudes above 1 brought back within the limits."""
    from scenes.motion import clip_curves
    tau = np.arange(240) / 60.0
    plain = clip_curves(kind, SKEL, 4, 1.5 * tau + 0.7)
    varied = clip_curves(kind, SKEL, 4, tau, speed=1.5, amplitude=0.8, phase=0.7)
    np.testing.assert_allclose(varied.angles, 0.8 * plain.angles, atol=1e-12)
    np.testing.assert_allclose(varied.rates, 0.8 * 1.5 * plain.rates, atol=1e-12)
    np.testing.assert_allclose(varied.travel, 0.8 * 1.5 * plain.travel, atol=1e-12)
    np.testing.assert_allclose(varied.offset_rate, 0.8 * 1.5 * plain.offset_rate, atol=1e-12)
    big = clip_curves(kind, SKEL, 4, tau, amplitude=3.0)
    assert (big.angles >= SKEL.joint_lower).all() and (big.angles <= SKEL.joint_upper).all()


def test_play_clips_fades_a_precomputed_motion_in_from_rest_and_out():
    """A raw Motion entry (as retargeted motion capture gives) keeps its length and name, starts and ends at
    rest next to procedural clips, and stays C1."""
    from scenes.motion import play_clips
    fps, blend = 60.0, 15
    raw = make_motion("karate", 90, fps, seed=1, settle_frames=0, blend_frames=1, skel=SKEL)
    raw = type(raw)(**{**raw.__dict__, "kind": "bvh:test", "root_position": raw.root_position + [0.0, 0.0, 0.3]})
    seq = play_clips(["dance", raw, "walk"], 300, 20, blend, seed=0, fps=fps)
    m = seq.motion
    assert seq.names == ("settle", "dance", "bvh:test", "walk") and np.bincount(seq.clip)[2] == 90
    first, last = np.flatnonzero(seq.clip == 2)[[0, -1]]
    for frame in (first, last):     # rest at both ends of the precomputed clip
        assert np.abs(m.joint_angles[frame]).max() < 1e-9 and np.abs(m.joint_angle_rates[frame]).max() < 1e-9
    middle = (first + last) // 2    # unscaled between its fades
    np.testing.assert_allclose(m.joint_angles[middle], raw.joint_angles[middle - first], atol=1e-12)
    fd = np.diff(m.joint_angles, axis=0) * fps
    assert np.abs(fd - 0.5 * (m.joint_angle_rates[1:] + m.joint_angle_rates[:-1])).max() \
        < 0.03 * np.abs(m.joint_angle_rates).max()
    assert np.linalg.norm(np.diff(m.root_position, axis=0), axis=1).max() < 2.0 / fps     # no jump in place
    with pytest.raises(ValueError, match="the clips take 110"):
        play_clips([raw], 200, 20, blend, seed=0, fps=fps)
