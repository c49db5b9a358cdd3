"""Skinning: weight rows are convex combinations of nearby parts, smoothing evens them out along the cloth, and
linear blend skinning reproduces the rest pose, moves rigidly with a single bone or a rigid body, and batches."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geometry.mesh import unique_edges
from scenes.capsules import capsule_signed_distance, capsules_world
from scenes.garments import make_garment
from scenes.kinematics import forward_kinematics, joint_quaternions, rest_transforms
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning, skinning_weights

SKEL = default_skeleton()
REST = rest_transforms(SKEL)


@pytest.fixture(scope="module")
def pants():
    g = make_garment("pants", SKEL)
    return g, skinning_weights(SKEL, g.vertices, g.faces)


def posed(**angles_deg):
    angles = np.zeros((SKEL.n_parts, 3))
    for name, values in angles_deg.items():
        angles[SKEL.index(name)] = np.radians(values)
    return forward_kinematics(SKEL, SKEL.joint_offsets[0], joint_quaternions(angles))


@pytest.mark.parametrize("kind", ["pants", "tshirt", "cape"])
def test_weight_rows_are_sorted_convex_combinations(kind):
    g = make_garment(kind, SKEL)
    indices, weights = skinning_weights(SKEL, g.vertices, g.faces, max_influences=4)
    assert indices.shape == weights.shape == (len(g.vertices), 4) and indices.dtype == np.int64
    assert indices.min() >= 0 and indices.max() < SKEL.n_parts
    assert (weights >= 0).all() and (np.diff(weights, axis=1) <= 0).all()
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-12)
    assert all(len(set(row)) == 4 for row in indices)                   # no part listed twice
    # The dominant influence is one of the two parts nearest the vertex.
    a, b, ra, rb = capsules_world(SKEL, REST)
    nearest_two = np.argsort(capsule_signed_distance(g.vertices, a, b, ra, rb), axis=1)[:, :2]
    assert (nearest_two == indices[:, :1]).any(axis=1).mean() > 0.97


def test_pants_weights_follow_the_legs(pants):
    g, (indices, weights) = pants
    names = np.array(SKEL.names)[indices[:, 0]]
    y, x = g.vertices[:, 1], g.vertices[:, 0]
    knee = (np.abs(y - 0.49) < 0.05)
    assert set(names[knee & (x > 0)]) <= {"thigh_l", "shin_l"} and set(names[knee & (x < 0)]) <= {"thigh_r", "shin_r"}
    assert set(names[g.attachment]) <= {"pelvis", "spine"}
    # Weights spread along the cloth, not through the air: the legs are close in space, but the right leg's pull
    # on the left trouser leg is a trace that seeps through the crotch seam and is gone by the knee.
    right_leg = np.isin(indices, [SKEL.index(n) for n in ("thigh_r", "shin_r", "foot_r")]) * weights
    assert right_leg[(x > 0) & (y < 0.75)].sum(axis=1).max() < 0.02
    assert right_leg[(x > 0) & (y < 0.45)].max() == 0.0


def test_smoothing_evens_out_weights_along_edges():
    g = make_garment("pants", SKEL)
    edges = unique_edges(g.faces)

    def steepest(blend_width):
        indices, weights = skinning_weights(SKEL, g.vertices, g.faces, max_influences=SKEL.n_parts,
                                            blend_width=blend_width)
        dense = np.zeros((len(g.vertices), SKEL.n_parts))
        np.put_along_axis(dense, indices, weights, axis=1)
        return np.abs(dense[edges[:, 0]] - dense[edges[:, 1]]).max()

    assert steepest(0.0) == 1.0                                        # nearest part only: a hard seam
    assert steepest(0.08) < 0.5 * steepest(0.0)


def test_lbs_reproduces_the_rest_pose_exactly(pants):
    g, (indices, weights) = pants
    np.testing.assert_allclose(linear_blend_skinning(g.vertices, indices, weights, REST, REST), g.vertices,
                               atol=1e-13)


def test_lbs_moves_rigidly_with_the_whole_body(pants):
    g, (indices, weights) = pants
    turn = Rotation.from_rotvec([0.3, -1.1, 0.4])
    shift = np.array([0.5, -0.2, 1.5])
    rotation = (turn * Rotation.from_quat(REST[0])).as_quat()
    translation = turn.apply(REST[1]) + shift
    moved = linear_blend_skinning(g.vertices, indices, weights, REST, (rotation, translation))
    np.testing.assert_allclose(moved, turn.apply(g.vertices) + shift, atol=1e-12)


def test_single_bone_vertices_follow_their_bone_rigidly(pants):
    g, _ = pants
    thigh = SKEL.index("thigh_l")
    indices = np.full((len(g.vertices), 2), [thigh, 0])
    weights = np.tile([1.0, 0.0], (len(g.vertices), 1))
    rotation, translation = posed(thigh_l=(-70, 20, 10), shin_l=(60, 0, 0))
    moved = linear_blend_skinning(g.vertices, indices, weights, REST, (rotation, translation))
    # By hand: into the thigh's rest frame, then out of its posed frame.
    local = Rotation.from_quat(REST[0][thigh]).inv().apply(g.vertices - REST[1][thigh])
    expected = Rotation.from_quat(rotation[thigh]).apply(local) + translation[thigh]
    np.testing.assert_allclose(moved, expected, atol=1e-12)
    pairwise = lambda p: np.linalg.norm(p[:50, None] - p[None, :50], axis=-1)   # noqa: E731
    np.testing.assert_allclose(pairwise(moved), pairwise(g.vertices), atol=1e-12)


def test_lbs_batches_over_frames_and_bends_the_leg_forward(pants):
    g, (indices, weights) = pants
    frames = [posed(thigh_l=(-a, 0, 0)) for a in (0, 45, 90)]
    rotation = np.stack([f[0] for f in frames])
    translation = np.stack([f[1] for f in frames])
    batched = linear_blend_skinning(g.vertices, indices, weights, REST, (rotation, translation))
    for k, frame in enumerate(frames):
        np.testing.assert_allclose(batched[k], linear_blend_skinning(g.vertices, indices, weights, REST, frame),
                                   atol=1e-13)
    hem = g.vertices[:, 1] < 0.2
    left, right = hem & (g.vertices[:, 0] > 0), hem & (g.vertices[:, 0] < 0)
    assert batched[2, left, 2].mean() > 0.5 and batched[2, left, 1].mean() > 0.7   # kicked up to hip height
    np.testing.assert_allclose(batched[2, right], g.vertices[right], atol=1e-3)     # the other leg stays


def test_invalid_parameters_are_named(pants):
    g, _ = pants
    with pytest.raises(ValueError, match="max_influences"):
        skinning_weights(SKEL, g.vertices, g.faces, max_influences=0)
