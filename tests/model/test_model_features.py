"""Input features of the upsampling network against independent references: analytic surfaces and motions, the
numpy capsule distance of scenes.capsules, a sparse-matrix Laplacian, finite differences, and rigid invariance."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse
import torch

from geometry.mesh import unique_edges
from geometry.shapes import cube_sphere, grid_patch
from model.features import (FEATURE_CHANNELS, FrameBatch, FrameStore, InputFeatures, capsule_distances,
                            nearest_capsule, previous_frames, principal_stretches, reference_neighbours,
                            umbrella_laplacian, vertex_normals)
from scenes.capsules import capsule_signed_distance
from model_meshes import identity_subdivider

F64 = torch.float64


def _t(array) -> torch.Tensor:
    return torch.as_tensor(np.asarray(array), dtype=F64)


def _random_rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _frame_inputs(positions, previous=None, before_previous=None, a=None, b=None, gravity=None,
                  frame_time=0.1, previous_output=None) -> FrameBatch:
    x = _t(positions)[None]
    a = _t([[[0.0, -2.0, 0.0]]]) if a is None else _t(a)
    b = _t([[[0.0, -3.0, 0.0]]]) if b is None else _t(b)
    radii = torch.full((a.shape[1],), 0.5, dtype=F64)
    return FrameBatch(x, x if previous is None else _t(previous)[None],
                       x if before_previous is None else _t(before_previous)[None], a, b, radii, radii.clone(),
                       _t([[0.0, -1.0, 0.0]]) if gravity is None else _t(gravity), frame_time,
                       0.01 * x if previous_output is None else _t(previous_output)[None])


def test_vertex_normals_converge_to_a_spheres_radial_direction_and_are_exact_on_a_plane():
    worst = []
    for n in (4, 8, 16):
        vertices, faces = cube_sphere(n, radius=2.0)
        normals = vertex_normals(_t(vertices)[None], torch.as_tensor(faces))[0].numpy()
        radial = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
        worst.append(np.degrees(np.arccos(np.clip((normals * radial).sum(1), -1, 1))).max())
    assert worst[-1] < 1.2 and worst[1] < 0.6 * worst[0] and worst[2] < 0.6 * worst[1]   # first order in h
    vertices, faces = grid_patch(5, 4)
    normals = vertex_normals(_t(vertices)[None], torch.as_tensor(faces))[0]
    torch.testing.assert_close(normals, _t([0.0, 0.0, 1.0]).expand_as(normals))


def test_umbrella_laplacian_matches_a_sparse_graph_laplacian():
    vertices, faces = cube_sphere(4)
    vertices = vertices * np.array([1.0, 0.6, 1.3])          # not a sphere: no symmetry to hide a mistake
    edges = unique_edges(faces)
    n = len(vertices)
    adjacency = scipy.sparse.coo_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]],
                                                                  np.r_[edges[:, 1], edges[:, 0]])), (n, n)).tocsr()
    valence = np.asarray(adjacency.sum(axis=1)).ravel()
    expected = scipy.sparse.diags(1.0 / valence) @ adjacency @ vertices - vertices
    got = umbrella_laplacian(_t(vertices)[None], torch.as_tensor(edges), _t(valence))[0]
    torch.testing.assert_close(got, _t(expected))


def test_capsule_distance_matches_the_numpy_implementation_and_its_gradient():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4, 3))
    b = a + rng.normal(size=(4, 3))
    radius_a, radius_b = rng.uniform(0.1, 0.4, 4), rng.uniform(0.05, 0.3, 4)
    points = rng.normal(size=(300, 3)) * 2
    distance, normal = capsule_distances(_t(points)[None], _t(a)[None], _t(b)[None], _t(radius_a), _t(radius_b))
    expected = capsule_signed_distance(points, a, b, radius_a, radius_b)
    np.testing.assert_allclose(distance[0].numpy(), expected, atol=1e-12)
    # the normal is the distance's gradient: central differences of the numpy distance
    h = 1e-6
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = h
        slope = (capsule_signed_distance(points + step, a, b, radius_a, radius_b)
                 - capsule_signed_distance(points - step, a, b, radius_a, radius_b)) / (2 * h)
        np.testing.assert_allclose(normal[0, ..., axis].numpy(), slope, atol=1e-5)


def test_nearest_capsule_by_hand():
    # a straight capsule of radius 0.5 along x from 0 to 1, and a ball-like one far away
    a, b = _t([[[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]]), _t([[[1.0, 0.0, 0.0], [10.0, 0.1, 0.0]]])
    radius = _t([0.5, 0.2])
    points = _t([[[0.5, 2.0, 0.0], [-1.5, 0.0, 0.0], [0.5, 0.0, 0.25], [9.0, 0.0, 0.0]]])
    distance, direction = nearest_capsule(points, a, b, radius, radius)
    torch.testing.assert_close(distance[0], _t([1.5, 1.0, -0.25, 0.8]))
    torch.testing.assert_close(direction[0], _t([[0, 1, 0], [-1, 0, 0], [0, 0, 1], [-1, 0, 0]]))


def test_principal_stretches_of_affine_maps_and_rigid_motion():
    vertices, faces = grid_patch(5, 6)
    rest, faces = _t(vertices), torch.as_tensor(faces)
    stretched = rest * _t([1.3, 0.8, 1.0])                       # x by 1.3, y by 0.8: every face alike
    torch.testing.assert_close(principal_stretches(stretched[None], rest, faces)[0],
                               _t([0.8, 1.3]).expand(len(rest), 2))
    moved = rest @ _t(_random_rotation(2)).T + _t([1.0, 2.0, 3.0])
    torch.testing.assert_close(principal_stretches(moved[None], rest, faces)[0], torch.ones(len(rest), 2, dtype=F64))
    sheared = rest.clone()
    sheared[:, 0] += 0.5 * rest[:, 1]                               # simple shear: stretches of [[1, .5], [0, 1]]
    singular = np.linalg.svd(np.array([[1.0, 0.5], [0.0, 1.0]]), compute_uv=False)
    torch.testing.assert_close(principal_stretches(sheared[None], rest, faces)[0],
                               _t(np.sort(singular)).expand(len(rest), 2))


def test_velocity_and_acceleration_are_exact_for_uniformly_accelerated_motion():
    vertices, faces = grid_patch(3, 3)
    u, g, dt = np.array([0.3, -0.2, 0.1]), np.array([0.0, -9.0, 2.0]), 0.05
    at = lambda t: vertices + u * t + 0.5 * g * t * t                   # noqa: E731
    features = InputFeatures(("velocity", "acceleration"), faces, vertices).double()
    got = features(_frame_inputs(at(2 * dt), at(dt), at(0.0), frame_time=dt))[0]
    # backward differences: velocity at the end of the step, u + g t - g dt / 2; acceleration exact
    torch.testing.assert_close(got[:, :3], _t(u + g * (2 * dt) - 0.5 * g * dt).expand(9, 3))
    torch.testing.assert_close(got[:, 3:], _t(g).expand(9, 3))


def test_features_stack_in_order_and_bad_names_are_refused():
    vertices, faces = grid_patch(3, 4)
    names = tuple(FEATURE_CHANNELS)
    features = InputFeatures(names, faces, vertices).double()
    got = features(_frame_inputs(vertices * 1.1))
    assert got.shape == (1, 12, features.channels) and features.channels == sum(features.groups())
    torch.testing.assert_close(got[0, :, :3], _t(vertices * 1.1))                       # position first
    for bad in (("position", "position"), ("colour",), ()):
        with pytest.raises(ValueError):
            InputFeatures(bad, faces, vertices)
    with pytest.raises(ValueError, match="normal"):
        InputFeatures(("normal",), faces, vertices, local_inputs=True)


@pytest.mark.parametrize("tangent", ["edge", "gravity"])
def test_body_relative_local_features_are_invariant_under_rigid_motion(tangent):
    vertices, faces = cube_sphere(3, radius=0.5)
    rng = np.random.default_rng(3)
    x = vertices + 0.02 * rng.normal(size=vertices.shape)
    previous, before = x - 0.01 * rng.normal(size=x.shape), x - 0.02 * rng.normal(size=x.shape)
    a, b = np.array([[[0.0, -0.8, 0.1], [0.3, 0.9, 0.0]]]), np.array([[[0.1, -1.5, 0.0], [0.2, 1.4, 0.3]]])
    gravity = np.array([[0.1, -1.0, 0.2]]) / math.sqrt(1.05)
    names = ("rest_position", "velocity", "acceleration", "body", "laplacian", "strain", "gravity")
    features = InputFeatures(names, faces, vertices, local_inputs=True, frame_tangent=tangent).double()
    rotation, shift = _random_rotation(4), np.array([0.5, -2.0, 1.0])
    move = lambda p: p @ rotation.T + shift                              # noqa: E731
    original = features(_frame_inputs(x, previous, before, a, b, gravity))
    moved = features(_frame_inputs(move(x), move(previous), move(before), move(a), move(b), gravity @ rotation.T))
    torch.testing.assert_close(moved, original)
    assert original[..., 3:].abs().amax(dim=(0, 1)).min() > 1e-3     # no feature is trivially zero


def test_reference_neighbours_share_an_edge_and_every_vertex_needs_a_face():
    vertices, faces = cube_sphere(3)
    reference = reference_neighbours(faces, len(vertices))
    edges = {tuple(e) for e in unique_edges(faces)}
    assert all(tuple(sorted((v, int(r)))) in edges for v, r in enumerate(reference))
    with pytest.raises(ValueError, match="no face"):
        reference_neighbours(faces, len(vertices) + 1)


def test_previous_frames_restart_at_each_sequence_and_batches_gather_history():
    previous = previous_frames(np.array([4, 4, 4, 7, 7, 2]))
    np.testing.assert_array_equal(previous, [0, 0, 1, 3, 3, 5])
    with pytest.raises(ValueError, match="contiguous"):
        previous_frames(np.array([1, 1, 2, 1]))
    positions = torch.arange(6, dtype=F64)[:, None, None].expand(6, 2, 3)          # frame f sits at f
    capsules = torch.zeros(6, 1, 3, dtype=F64)
    source = FrameStore(positions, identity_subdivider(2), torch.as_tensor(previous), capsules, capsules,
                        torch.ones(1), torch.ones(1),
                         torch.zeros(6, 3, dtype=F64), 0.5)
    batch = source.batch(torch.tensor([2, 3, 4]))
    assert batch.positions[:, 0, 0].tolist() == [2, 3, 4]
    assert batch.previous[:, 0, 0].tolist() == [1, 3, 3]
    assert batch.before_previous[:, 0, 0].tolist() == [0, 3, 3]
