"""Tet meshes (geometry.tets) and the marching-tetrahedra surface (geometry.isosurface) against analytic cases."""
import numpy as np
import pytest

from geometry.isosurface import marching_tetrahedra, relax_on_surface, triangle_angles
from geometry.mesh import validate_mesh
from geometry.tets import dihedral_angles, kuhn_grid, radius_ratios, tet_volumes

REGULAR = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1]], dtype=float)   # positively oriented


def test_quality_measures_of_a_regular_a_kuhn_and_a_flat_tet():
    tet = np.array([[0, 1, 2, 3]])
    assert tet_volumes(REGULAR, tet)[0] == pytest.approx(8 / 3)
    np.testing.assert_allclose(dihedral_angles(REGULAR, tet), np.degrees(np.arccos(1 / 3)))
    assert radius_ratios(REGULAR, tet)[0] == pytest.approx(1.0)
    flat = REGULAR * np.array([1, 1, 1e-6])
    assert radius_ratios(flat, tet)[0] < 1e-5
    nodes, tets = kuhn_grid((1, 1, 1), np.zeros(3), 2.0)
    angles = np.sort(dihedral_angles(nodes, tets), axis=1)
    np.testing.assert_allclose(angles, np.tile([45, 45, 60, 90, 90, 90], (6, 1)), atol=1e-9)
    # A Kuhn tet of the unit cube: volume 1/6, faces of area 1/2, 1/2, sqrt(2)/2, sqrt(2)/2, so r_in = 3 V / A =
    # 1 / (2 (1 + sqrt 2)); its corners are the cube's, so r_circ = sqrt(3) / 2.
    np.testing.assert_allclose(radius_ratios(nodes, tets), 3 / (2 * (1 + np.sqrt(2))) / (np.sqrt(3) / 2))


def test_a_kuhn_grid_fills_its_box_with_positive_tets_whose_faces_match():
    nodes, tets = kuhn_grid((3, 2, 4), np.array([1.0, -2.0, 0.5]), 0.25)
    volumes = tet_volumes(nodes, tets)
    assert (volumes > 0).all() and volumes.sum() == pytest.approx(0.75 * 0.5 * 1.0)
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]),
                    axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() == 2                       # conforming: an inner face is two tets', a boundary face one's
    boundary_faces = (counts == 1).sum()
    assert boundary_faces == 2 * 2 * (3 * 2 + 2 * 4 + 3 * 4)   # two triangles per boundary square


def test_marching_tetrahedra_of_a_sphere_is_a_closed_sphere_and_relaxing_evens_it():
    sdf = lambda p: np.linalg.norm(p, axis=1) - 1.0  # noqa: E731
    nodes, tets = kuhn_grid((16, 16, 16), np.full(3, -1.2), 0.15)
    vertices, faces = marching_tetrahedra(nodes, tets, sdf(nodes))
    validate_mesh(vertices, faces)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    assert len(vertices) - len(edges) + len(faces) == 2                         # a sphere's Euler characteristic
    v = vertices[faces]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
    assert volume == pytest.approx(4 / 3 * np.pi, rel=0.03)                    # outward: positive volume
    assert np.abs(sdf(vertices)).max() < 0.15 ** 2                              # linear interpolation's error
    relaxed = relax_on_surface(vertices, faces, sdf, 10, 1e-4)
    validate_mesh(relaxed, faces)
    assert np.abs(sdf(relaxed)).max() < 1e-9
    assert triangle_angles(vertices, faces).min() < 5 < 20 < triangle_angles(relaxed, faces).min()


def test_a_function_that_never_changes_sign_has_no_surface():
    nodes, tets = kuhn_grid((2, 2, 2), np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="no surface"):
        marching_tetrahedra(nodes, tets, np.ones(len(nodes)))
