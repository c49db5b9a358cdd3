"""The hand's joint-angle trajectories (scenes.hand_motion): within the limits, smooth, seeded, from rest."""
import numpy as np
import pytest

from scenes.hand_motion import fist_trajectory, random_trajectory, sequence_angles
from scenes.hand_skeleton import ANGLE_LIMITS, ANGLE_NAMES, fist_angles, hand_transforms, hand_skeleton, part_angles


def test_random_trajectories_start_at_rest_stay_within_the_limits_and_are_smooth_and_seeded():
    a = random_trajectory(600, 30.0, seed=4)
    assert a.shape == (600, 18) and (a[0] == 0).all()
    assert (a >= ANGLE_LIMITS[:, 0] - 1e-12).all() and (a <= ANGLE_LIMITS[:, 1] + 1e-12).all()
    part_angles(hand_skeleton(), a)                                     # the skeleton accepts every frame
    # Smootherstep between keyframes at least 0.4 s apart: a step of at most 15/8 the range over 12 frames.
    speed = np.abs(np.diff(a, axis=0))
    assert (speed <= 15 / 8 * np.ptp(ANGLE_LIMITS, axis=1) / 12 + 1e-12).all()
    assert (np.abs(np.diff(a, 2, axis=0)) < 0.05).all()                 # no kinks (C2 blends)
    # Each angle explores its range, and the angles are not in lockstep.
    assert (np.ptp(a, axis=0) > 0.4 * np.ptp(ANGLE_LIMITS, axis=1)).all()
    assert np.abs(np.corrcoef(a.T)[np.triu_indices(18, 1)]).max() < 0.9
    np.testing.assert_array_equal(a, random_trajectory(600, 30.0, seed=4))
    assert not np.array_equal(a, random_trajectory(600, 30.0, seed=5))


def test_the_fist_closes_finger_by_finger_holds_and_opens():
    a = fist_trajectory(100)
    assert (a[0] == 0).all() and np.abs(a[-1]).max() < 1e-12
    np.testing.assert_allclose(a[75], fist_angles(1.0), atol=1e-12)     # held closed
    pip = {f: a[:, ANGLE_NAMES.index(f"{f}_pip_flexion")] for f in ("little", "ring", "middle", "index")}
    first_moves = [np.argmax(pip[f] > 1e-3) for f in ("little", "ring", "middle", "index")]
    assert first_moves == sorted(first_moves) and len(set(first_moves)) == 4
    assert (a >= ANGLE_LIMITS[:, 0] - 1e-12).all() and (a <= ANGLE_LIMITS[:, 1] + 1e-12).all()
    hand_transforms(hand_skeleton(), a)


@pytest.mark.parametrize("call", [lambda: random_trajectory(0, 30.0, 1),
                                  lambda: random_trajectory(10, 30.0, 1, 1.0, 0.5), lambda: fist_trajectory(5)])
def test_impossible_requests_are_refused(call):
    with pytest.raises(ValueError):
        call()


DRIVE = {"seed": 7, "min_interval": 0.5, "max_interval": 1.0, "test_motions": ["fist"]}


def test_a_sequence_plays_the_trajectory_its_name_and_the_drive_say():
    np.testing.assert_array_equal(sequence_angles("train_002", 50, 60.0, DRIVE),
                                  random_trajectory(50, 60.0, 9, 0.5, 1.0))       # seed 7 + index 2
    np.testing.assert_array_equal(sequence_angles("held_out_000", 50, 60.0, DRIVE), fist_trajectory(50))
    for name in ("held_out_001", "train_x"):
        with pytest.raises(ValueError, match=name):
            sequence_angles(name, 50, 60.0, DRIVE)
