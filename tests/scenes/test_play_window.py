"""A library window played the paper's way (scenes.motion.play_window): from the rest pose (where the scene's settle
sequence, scenes.motion.at_rest, left the cloth), blended into the clip's first pose, held there, then the clip
untouched; and the check that drops a window whose pose drives worn limbs through each other
(scenes.capsules.limbs_through_each_other)."""
import dataclasses

import numpy as np
import pytest

from scenes.capsules import limbs_through_each_other, self_collision_pairs
from scenes.kinematics import rest_transforms
from scenes.motion import at_rest, body_state, make_motion, play_window
from scenes.skeleton import default_skeleton

SKEL = default_skeleton()
FPS = 60.0


@pytest.fixture(scope="module")
def clip():
    """The middle of a dance: its first frame is a pose in motion, as a window's is."""
    dance = make_motion("dance", 190, FPS, seed=3, settle_frames=0, blend_frames=10, skel=SKEL)
    motion = dataclasses.replace(dance, **{name: getattr(dance, name)[100:] for name in (
        "root_position", "root_velocity", "joint_angles", "joint_angle_rates")})
    assert np.abs(motion.joint_angles[0]).max() > 0.1 and np.abs(motion.joint_angle_rates[0]).max() > 0.1
    return motion


def test_from_rest_blend_then_hold_then_the_clip_as_it_is(clip):
    played = play_window(clip, blend_frames=20, hold_frames=15, skel=SKEL)
    motion, lead_in = played.motion, 20 + 15
    assert motion.n_frames == lead_in + clip.n_frames and played.names == ("settle", clip.kind)
    assert (played.clip[:lead_in] == 0).all() and (played.clip[lead_in:] == 1).all()
    # Frame 0 is the settle sequence's pose, at rest: where the settled cloth was left (the blend's first rates
    # are its smoothed ground lift's, a few mm/s).
    settle = at_rest(7, FPS, SKEL)
    assert settle.names == ("settle",) and (settle.clip == 0).all() and settle.motion.n_frames == 7
    for name in ("root_position", "root_velocity", "joint_angles", "joint_angle_rates"):
        assert (getattr(settle.motion, name) == getattr(settle.motion, name)[0]).all()
        np.testing.assert_allclose(getattr(motion, name)[0], getattr(settle.motion, name)[-1], rtol=0,
                                   atol=0.0 if name in ("root_position", "joint_angles") else 0.01)
    np.testing.assert_allclose(motion.joint_angles[19:35], clip.joint_angles[0][None].repeat(16, 0))   # held
    np.testing.assert_allclose(motion.root_position[19:35], clip.root_position[0][None].repeat(16, 0), atol=1e-12)
    assert np.abs(motion.joint_angle_rates[19:35]).max() == 0.0 and np.abs(motion.root_velocity[20:35]).max() == 0
    for name in ("root_position", "root_velocity", "joint_angles", "joint_angle_rates"):
        np.testing.assert_array_equal(getattr(motion, name)[lead_in:], getattr(clip, name))


def test_the_blend_is_smooth_and_its_rates_are_its_derivatives(clip):
    motion = play_window(clip, blend_frames=40, hold_frames=5, skel=SKEL).motion
    blend = slice(0, 40)
    angles, rates = motion.joint_angles[blend], motion.joint_angle_rates[blend]
    np.testing.assert_allclose(np.gradient(angles, 1 / FPS, axis=0)[1:-1], rates[1:-1], atol=0.05)
    root, velocity = motion.root_position[blend], motion.root_velocity[blend]
    np.testing.assert_allclose(np.gradient(root, 1 / FPS, axis=0)[1:-1], velocity[1:-1], atol=0.01)
    assert np.abs(rates[0]).max() < 1e-9 and np.abs(rates[-1]).max() < 1e-9      # starts and ends still
    # the feet stay above the floor through the blend (ground_lift), as they are at rest and in the clip
    from scenes.capsules import capsules_world
    a, b, ra, rb = capsules_world(SKEL, body_state(SKEL, motion).transforms)
    feet = [SKEL.index("foot_l"), SKEL.index("foot_r")]
    lowest = np.minimum(a[:, feet, 1] - ra[:, feet], b[:, feet, 1] - rb[:, feet]).min(axis=1)
    rest_lowest = lowest[0]
    assert lowest[blend].min() > rest_lowest - 0.01


def test_a_window_needs_a_blend_and_a_clip():
    short = make_motion("walk", 1, FPS, settle_frames=0, blend_frames=1, skel=SKEL)
    with pytest.raises(ValueError, match="a window needs"):
        play_window(short, 5, 5, SKEL)


def test_limbs_that_pass_through_each_other_are_found_and_touching_ones_are_not():
    pairs = self_collision_pairs(SKEL)
    rest = tuple(x[None] for x in rest_transforms(SKEL))
    assert limbs_through_each_other(SKEL, rest, pairs) is None
    thigh = SKEL.index("thigh_l")
    rotation, translation = (x.copy() for x in rest)
    # Move the left thigh across onto the right one: its axis inside the other capsule.
    translation[0, thigh] += translation[0, SKEL.index("thigh_r")] - translation[0, thigh]
    found = limbs_through_each_other(SKEL, (rotation, translation), pairs)
    assert found is not None and set(found[2]) == {"thigh_l", "thigh_r"} and found[1] == 0 and found[0] > 0.1
    # Half a thigh radius apart from touching: close, sinking in a little at most, not through.
    rotation, translation = (x.copy() for x in rest)
    gap = translation[0, SKEL.index("thigh_r")] - translation[0, thigh]
    radius = (SKEL.radius_a[thigh] + SKEL.radius_b[thigh]) / 2
    translation[0, thigh] += gap * (1 - (2 * radius * 0.75) / np.linalg.norm(gap))
    assert limbs_through_each_other(SKEL, (rotation, translation), pairs) is None
