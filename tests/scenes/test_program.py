"""Motion programs: seeded plans, C¹ motion (finite differences at a high frame rate), joint limits, the settle
period, crossfades that sum to one, precomputed clips played unscaled, and feet on the ground."""
import numpy as np
import pytest

from scenes.capsules import capsules_world
from scenes.motion import body_state, make_motion
from scenes.program import ProgramClip, plan_program, play_program
from scenes.skeleton import default_skeleton

SKEL = default_skeleton()
POOL = ["dance", "karate", "random", "walk"]


def program(seed, pool=POOL, n_frames=420, settle=30, blend=20, fps=60.0):
    plan = plan_program(pool, n_frames, settle, blend, fps, np.random.default_rng(seed))
    return plan, play_program(plan, n_frames, settle, blend, seed, fps, SKEL)


@pytest.fixture(scope="module")
def fine():
    """A program at 1200 fps (blend 0.33 s), for finite-difference checks of its derivatives."""
    fps = 1200.0
    plan = plan_program(POOL, 7200, 600, 400, fps, np.random.default_rng(7))
    return fps, plan, play_program(plan, 7200, 600, 400, 7, fps, SKEL)


def test_plans_and_motions_are_seeded():
    (plan_a, seq_a), (plan_b, seq_b), (plan_c, seq_c) = program(3), program(3), program(4)
    assert [c.name for c in plan_a] == [c.name for c in plan_b]
    np.testing.assert_array_equal(seq_a.motion.joint_angles, seq_b.motion.joint_angles)
    np.testing.assert_array_equal(seq_a.motion.root_position, seq_b.motion.root_position)
    assert np.abs(seq_a.motion.joint_angles - seq_c.motion.joint_angles).max() > 0.1


def test_programs_vary_speed_amplitude_order_and_transitions():
    plans = [program(seed)[0] for seed in range(6)]
    clips = [c for plan in plans for c in plan]
    assert len({c.speed for c in clips}) == len(clips) and len({c.amplitude for c in clips}) == len(clips)
    assert len({tuple(c.name for c in plan[:2]) for plan in plans}) > 2          # different orders
    crossfades = pauses = 0
    for plan in plans:
        for before, after in zip(plan, plan[1:]):
            if after.start < before.end:        # a crossfade: the fade-in is the fade-out
                assert (after.start, after.fade_in) == (before.end - before.fade_out, before.fade_out)
                crossfades += 1
            else:
                pauses += 1
    assert crossfades and pauses


def test_the_motion_is_c1(fine):
    fps, plan, seq = fine
    m = seq.motion
    central = lambda x: (x[2:] - x[:-2]) * fps / 2                   # noqa: E731
    # A kink (a jump in a rate) leaves an error of the order of the rates (several rad/s, m/s) at any frame rate;
    # these bounds are far smaller. Keyframed clips are C¹ only: their second derivative jumps where a held pose
    # is left (a jump of ~400 rad/s² for a brisk, sped-up karate kick), which costs ~jump / (4 fps) here.
    assert np.abs(m.joint_angle_rates).max() > 4.0
    np.testing.assert_allclose(m.joint_angle_rates[1:-1], central(m.joint_angles), atol=0.15)
    np.testing.assert_allclose(m.root_velocity[1:-1], central(m.root_position), atol=5e-3)
    state = body_state(SKEL, m)
    np.testing.assert_allclose(state.linear_velocity[1:-1], central(state.translation), atol=0.05)
    assert len(plan) >= 3


def test_angles_stay_within_the_limits_and_settle_frames_at_rest():
    for seed in range(4):
        plan, seq = program(seed)
        m = seq.motion
        assert (m.joint_angles >= SKEL.joint_lower - 1e-12).all()
        assert (m.joint_angles <= SKEL.joint_upper + 1e-12).all()
        settle = slice(0, 31)
        assert np.abs(m.joint_angles[settle]).max() == 0 and np.abs(m.joint_angle_rates[settle]).max() == 0
        np.testing.assert_allclose(m.root_position[settle], np.broadcast_to(SKEL.joint_offsets[0], (31, 3)), atol=0)
        assert (seq.clip[:31] == 0).all() and (seq.clip[31:] > 0).all()
        assert seq.names == ("settle", *(c.name for c in plan)) and set(seq.names[1:]) <= set(POOL)
        # a clip's frames run from where it starts to weigh most to where the next one does (rests between
        # clips belong to the clip before)
        starts = [np.flatnonzero(seq.clip == k).min() for k in range(1, len(plan) + 1)]
        assert starts == sorted(starts) and all(start > clip.start for start, clip in zip(starts, plan))
        assert all(start <= clip.start + clip.fade_in for start, clip in zip(starts, plan))


def test_feet_stay_on_the_ground():
    _, seq = program(1)
    a, b, ra, rb = capsules_world(SKEL, body_state(SKEL, seq.motion).transforms)
    feet = [SKEL.index("foot_l"), SKEL.index("foot_r")]
    lowest = np.minimum(a[:, feet, 1] - ra[:, feet], b[:, feet, 1] - rb[:, feet]).min(axis=1)
    assert np.abs(lowest).max() < 0.03       # within 3 cm of y = 0, through crossfades and speed changes


def test_a_precomputed_clip_plays_unscaled_at_its_own_length():
    """A Motion in the pool (motion capture) keeps its length, speed and amplitude: between its fades the program
    plays it exactly, starting wherever the body stands."""
    raw = make_motion("dance", 150, 60.0, seed=9, settle_frames=0, blend_frames=1, skel=SKEL)
    plans = [plan_program([raw], 420, 30, 20, 60.0, np.random.default_rng(seed)) for seed in range(20)]
    for plan in plans:
        assert all(c.end - c.start == 150 and c.speed == 1 and c.amplitude == 1 for c in plan if c.source is raw)
        assert all(c.source == "rest" for c in plan if c.source is not raw)     # the filler of a full sequence
    # The first clip follows the settle period; where the next one starts after it has faded out, nothing
    # overlaps it and its plateau is the clip itself.
    plan = next(p for p in plans if p[1].start >= p[0].end)
    seq = play_program(plan, 420, 30, 20, 0, 60.0, SKEL)
    clip = plan[0]
    plateau = slice(clip.start + clip.fade_in, clip.end - clip.fade_out)
    offset = clip.fade_in
    np.testing.assert_allclose(seq.motion.joint_angles[plateau],
                               raw.joint_angles[offset:offset + plateau.stop - plateau.start], atol=1e-12)


def test_bad_plans_are_value_errors():
    with pytest.raises(ValueError, match="a program needs clips"):
        plan_program([], 100, 10, 5, 60.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="more frames than settle frames"):
        plan_program(["walk"], 10, 10, 5, 60.0, np.random.default_rng(0))
    assert ProgramClip("walk", 0, 10, 2, 2).name == "walk"
