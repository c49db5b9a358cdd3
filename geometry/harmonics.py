"""Harmonic test functions (Kavan et al. 2011): the lowest-frequency eigenfunctions of the cotangent Laplacian.

The high-resolution simulation is constrained so that its projection onto these functions matches the subdivided
low-resolution mesh, which pins its low frequencies to the coarse solution and leaves the detail free. Following
the paper, a mesh with V vertices uses ceil(V / 40) of them.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg

from geometry.mesh import validate_mesh

# Shift-invert needs L - σM nonsingular; L is singular (constants), so σ sits just below 0, relative to the
# mesh's stiffest mode so that the shift means the same on meshes of any scale.
_RELATIVE_SHIFT = 1e-8


def cotan_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Positive semi-definite cotangent Laplacian L (V, V): Σ_edges (cot α + cot β)/2 (e_i - e_j)(e_i - e_j)ᵀ.

    A boundary edge has only one opposite angle and so one cotangent. xᵀ L x is the Dirichlet energy
    ∫|∇x|² of the piecewise-linear function with vertex values x.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    corners = vertices[faces]  # (F, 3 corners, 3)
    # The angle at corner i lies between the edges to the other two corners, and faces the edge joining them.
    to_next = np.roll(corners, -1, axis=1) - corners
    to_prev = np.roll(corners, 1, axis=1) - corners
    cross_norm = np.linalg.norm(np.cross(to_next, to_prev), axis=2)
    half_cot = 0.5 * np.einsum("fij,fij->fi", to_next, to_prev) / cross_norm  # (F, 3)
    j = np.roll(faces, -1, axis=1).ravel()
    k = np.roll(faces, 1, axis=1).ravel()
    w = half_cot.ravel()
    n = len(vertices)
    laplacian = sp.csr_matrix((np.concatenate([-w, -w, w, w]),
                               (np.concatenate([j, k, j, k]), np.concatenate([k, j, j, k]))), shape=(n, n))
    laplacian.sort_indices()
    return laplacian


def lumped_mass(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Barycentric lumped mass (V,): one third of the area of every triangle touching the vertex."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    v = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    return np.bincount(faces.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def harmonic_count(n_vertices: int, vertices_per_harmonic: int = 40) -> int:
    """Number of harmonic test functions for a mesh of `n_vertices` vertices: ceil(V / 40) in the paper."""
    if n_vertices < 0:
        raise ValueError(f"vertex count must be >= 0, got {n_vertices}")
    if vertices_per_harmonic < 1:
        raise ValueError(f"vertices per harmonic must be >= 1, got {vertices_per_harmonic}")
    return math.ceil(n_vertices / vertices_per_harmonic)


def harmonic_basis(vertices: np.ndarray, faces: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k lowest eigenpairs of L b = λ M b: basis (V, k) with Bᵀ M B = I, eigenvalues (k,) ascending, mass (V,).

    Deterministic: ARPACK starts from a fixed vector. A final Rayleigh-Ritz step in the computed subspace makes
    the basis M-orthonormal to machine precision even inside the (near-)degenerate clusters of symmetric shapes.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    validate_mesh(vertices, faces)
    n = len(vertices)
    if not 1 <= k < n:
        raise ValueError(f"number of harmonics must lie in [1, {n - 1}] for a mesh of {n} vertices, got {k}")
    laplacian = cotan_laplacian(vertices, faces)
    mass = lumped_mass(vertices, faces)
    mass_matrix = sp.diags(mass, format="csc")
    sigma = -_RELATIVE_SHIFT * float(np.max(laplacian.diagonal() / mass))
    start = np.random.default_rng(0).standard_normal(n)
    _, vectors = scipy.sparse.linalg.eigsh(laplacian.tocsc(), k=k, M=mass_matrix, sigma=sigma, which="LM", v0=start)
    projected_l = vectors.T @ (laplacian @ vectors)
    projected_m = vectors.T @ (mass[:, None] * vectors)
    eigenvalues, rotation = scipy.linalg.eigh(0.5 * (projected_l + projected_l.T), 0.5 * (projected_m + projected_m.T))
    return vectors @ rotation, eigenvalues, mass
