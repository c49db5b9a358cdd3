"""Per-vertex local frames: orthonormal and right-handed, the normal as third axis, an exact round trip, and a
gravity-hinted tangent that follows the hint."""
from __future__ import annotations

import numpy as np
import torch

from geometry.shapes import cube_sphere, grid_patch
from model.features import reference_neighbours, vertex_normals
from model.local_frames import to_global, to_local, vertex_frames


def _frames(vertices, faces, hint=None):
    x = torch.as_tensor(vertices, dtype=torch.float64)[None]
    normals = vertex_normals(x, torch.as_tensor(faces))
    reference = torch.as_tensor(reference_neighbours(faces, len(vertices)))
    return vertex_frames(x, normals, reference, hint), normals


def test_frames_are_rotations_with_the_normal_last():
    vertices, faces = cube_sphere(4)
    vertices = vertices * np.array([1.0, 0.5, 0.8])
    for hint in (None, torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64)):
        frames, normals = _frames(vertices, faces, hint)
        eye = torch.eye(3, dtype=torch.float64).expand_as(frames)
        torch.testing.assert_close(frames @ frames.transpose(-1, -2), eye)
        torch.testing.assert_close(torch.linalg.det(frames), torch.ones(frames.shape[:2], dtype=torch.float64))
        torch.testing.assert_close(frames[..., 2, :], normals)


def test_round_trip_is_exact_and_local_normal_component_is_the_dot_product():
    vertices, faces = cube_sphere(3)
    frames, normals = _frames(vertices, faces)
    vectors = torch.randn(1, len(vertices), 3, dtype=torch.float64)
    local = to_local(frames, vectors)
    torch.testing.assert_close(to_global(frames, local), vectors)
    torch.testing.assert_close(local[..., 2], (vectors * normals).sum(-1))
    torch.testing.assert_close(local.norm(dim=-1), vectors.norm(dim=-1))


def test_gravity_tangent_follows_the_hint_on_a_hanging_sheet():
    vertices, faces = grid_patch(5, 5)        # the xy-plane, normals +z: gravity (0, -1, 0) lies in it
    frames, _ = _frames(vertices, faces, torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64))
    angle = torch.rad2deg(torch.acos(frames[0, :, 0, 1].neg().clamp(-1, 1)))
    assert angle.max() < 3.0                   # only the edge tie-break turns it
    edge_frames, _ = _frames(vertices, faces)
    assert torch.rad2deg(torch.acos(edge_frames[0, :, 0, 1].neg().clamp(-1, 1))).max() > 30.0
