"""Cotangent Laplacian, lumped mass and harmonic basis against dense solves, FEM energies and the sphere's
analytic spectrum."""
import numpy as np
import pytest
import scipy.linalg
import trimesh

from geometry.harmonics import cotan_laplacian, harmonic_basis, harmonic_count, lumped_mass


def bumpy_sphere(subdivisions=1, seed=0):
    """Icosphere with random radii: closed, and without the symmetry that makes eigenvalues repeat."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    radii = np.random.default_rng(seed).uniform(0.85, 1.15, (len(sphere.vertices), 1))
    return np.asarray(sphere.vertices) * radii, np.asarray(sphere.faces)


def jittered_patch(n=6, seed=0, height=0.0):
    """Flat (or, with height, bumpy) n×n grid patch in the xy plane with jittered interior vertices."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    rng = np.random.default_rng(seed)
    xy = np.stack([i, j], axis=-1).astype(np.float64)
    xy[1:-1, 1:-1] += rng.uniform(-0.3, 0.3, (n - 1, n - 1, 2))
    z = rng.uniform(-height, height, i.shape)
    vertices = np.concatenate([xy.reshape(-1, 2), z.reshape(-1, 1)], axis=1)
    a = (i[:-1, :-1] * (n + 1) + j[:-1, :-1]).ravel()
    b, c, d = a + n + 1, a + n + 2, a + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return vertices, faces


def dirichlet_energy(vertices, faces, values):
    """Σ_faces area · |∇f|² of the piecewise-linear interpolant, gradients from each triangle's own edges."""
    corners = vertices[faces]
    edges = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], axis=1)  # (F, 2, 3)
    rises = np.stack([values[faces[:, 1]] - values[faces[:, 0]], values[faces[:, 2]] - values[faces[:, 0]]], 1)
    gradients = np.einsum("fij,fj->fi", np.linalg.pinv(edges), rises)  # minimum norm = in the triangle's plane
    area = 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    return float(np.sum(area * np.sum(gradients ** 2, axis=1)))


@pytest.mark.parametrize("make", [bumpy_sphere, lambda: jittered_patch(height=0.4)], ids=["sphere", "patch"])
def test_laplacian_is_the_dirichlet_energy(make):
    vertices, faces = make()
    laplacian = cotan_laplacian(vertices, faces)
    assert abs(laplacian - laplacian.T).max() == 0
    np.testing.assert_allclose(laplacian @ np.ones(len(vertices)), 0, atol=1e-12)
    rng = np.random.default_rng(5)
    for values in rng.normal(size=(3, len(vertices))):
        np.testing.assert_allclose(values @ (laplacian @ values), dirichlet_energy(vertices, faces, values),
                                   rtol=1e-10)
    assert np.linalg.eigvalsh(laplacian.toarray()).min() > -1e-10


def test_laplacian_of_linear_function_vanishes_inside_flat_patch():
    vertices, faces = jittered_patch()
    linear = vertices @ np.array([0.7, -1.3, 0.0]) + 2.0
    response = cotan_laplacian(vertices, faces) @ linear
    n = 7
    interior = np.zeros((n, n), dtype=bool)
    interior[1:-1, 1:-1] = True
    np.testing.assert_allclose(response[interior.ravel()], 0, atol=1e-12)
    assert np.abs(response[~interior.ravel()]).max() > 0.1  # the boundary flux is not zero


def test_mass_sums_to_area_and_splits_faces_in_thirds():
    vertices, faces = bumpy_sphere()
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mass = lumped_mass(vertices, faces)
    np.testing.assert_allclose(mass.sum(), mesh.area, rtol=1e-12)
    per_vertex = [mesh.area_faces[f[f >= 0]].sum() / 3 for f in mesh.vertex_faces]
    np.testing.assert_allclose(mass, per_vertex, rtol=1e-12)


@pytest.mark.parametrize("make", [bumpy_sphere, lambda: jittered_patch(height=0.4)], ids=["sphere", "patch"])
def test_basis_matches_dense_generalized_eigensolve(make):
    vertices, faces = make()
    k = 10
    basis, eigenvalues, mass = harmonic_basis(vertices, faces, k)
    assert basis.shape == (len(vertices), k) and basis.dtype == np.float64 and eigenvalues.shape == (k,)
    dense_values, dense_vectors = scipy.linalg.eigh(cotan_laplacian(vertices, faces).toarray(), np.diag(mass))
    np.testing.assert_allclose(eigenvalues, dense_values[:k], atol=1e-9 * dense_values[k])
    assert np.all(np.diff(eigenvalues) >= 0)
    # The bumpy shapes have simple eigenvalues, so each vector is the dense one up to sign.
    overlap = np.abs(np.sum(basis * mass[:, None] * dense_vectors[:, :k], axis=0))
    np.testing.assert_allclose(overlap, 1.0, atol=1e-8)


def test_closed_mesh_starts_with_constant_and_is_m_orthonormal():
    vertices, faces = bumpy_sphere(subdivisions=2)
    basis, eigenvalues, mass = harmonic_basis(vertices, faces, 20)
    assert abs(eigenvalues[0]) < 1e-10 * eigenvalues[1]
    np.testing.assert_allclose(np.abs(basis[:, 0]), 1 / np.sqrt(mass.sum()), rtol=1e-8)
    np.testing.assert_allclose(basis.T @ (mass[:, None] * basis), np.eye(20), atol=1e-8)


def test_sphere_spectrum_approaches_spherical_harmonics():
    radius = 2.0
    degree = np.repeat(np.arange(4), [1, 3, 5, 7])  # multiplicities 2l+1
    expected = degree * (degree + 1) / radius ** 2
    errors = []
    for subdivisions in (3, 4):
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
        _, eigenvalues, _ = harmonic_basis(sphere.vertices, sphere.faces, 16)
        assert abs(eigenvalues[0]) < 1e-8
        errors.append(np.max(np.abs(eigenvalues[1:] / expected[1:] - 1)))
    assert errors[1] < 5e-3
    assert errors[0] > 3 * errors[1]  # second-order convergence: halving the edge length quarters the error


def test_basis_is_deterministic():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    first = harmonic_basis(sphere.vertices, sphere.faces, 17)
    second = harmonic_basis(sphere.vertices, sphere.faces, 17)
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


def test_harmonic_count_is_ceil_of_v_over_40():
    assert [harmonic_count(v) for v in (0, 1, 40, 41, 80, 15000, 15001)] == [0, 1, 1, 2, 2, 375, 376]
    assert [harmonic_count(v, 20) for v in (20, 21, 15000)] == [1, 2, 750]
    with pytest.raises(ValueError):
        harmonic_count(-1)
    with pytest.raises(ValueError):
        harmonic_count(100, 0)


def test_rejects_impossible_count():
    vertices, faces = jittered_patch(n=2)
    with pytest.raises(ValueError, match="number of harmonics"):
        harmonic_basis(vertices, faces, len(vertices))
    with pytest.raises(ValueError, match="number of harmonics"):
        harmonic_basis(vertices, faces, 0)
