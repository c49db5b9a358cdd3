"""Constraint assembly on the host (numpy): the cloth's distance constraints and the harmonic constraint of a
high-res run. The solver lays them out on the device (`kernels.DistanceConstraints`, `kernels.HarmonicProjection`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.mesh import bending_pairs, unique_edges
from sim.xpbd.settings import SolverSettings


@dataclass(frozen=True)
class DistancePairs:
    """Two-vertex constraints rest_min <= |x_i - x_j| <= rest_max with a compliance each, one row per pair."""
    pairs: np.ndarray       # (C, 2) int
    rest_min: np.ndarray    # (C,)
    rest_max: np.ndarray    # (C,)
    compliance: np.ndarray  # (C,)


def cloth_constraints(rest_vertices: np.ndarray, faces: np.ndarray, s: SolverSettings) -> DistancePairs:
    """Stretch constraints on every edge (compression allowed to `compression_allowance`) and, if bending is on,
    a link between the two vertices opposite each interior edge, at its rest length."""
    edges = unique_edges(faces)
    length = np.linalg.norm(rest_vertices[edges[:, 0]] - rest_vertices[edges[:, 1]], axis=1)
    parts = [(edges, s.compression_allowance * length, length, np.full(len(edges), s.stretch_compliance))]
    if s.bending:
        links = bending_pairs(faces)
        link_length = np.linalg.norm(rest_vertices[links[:, 0]] - rest_vertices[links[:, 1]], axis=1)
        parts.append((links, link_length, link_length, np.full(len(links), s.bending_compliance)))
    return DistancePairs(*(np.concatenate(p) for p in zip(*parts)))


def vertex_incidence(pairs: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR of constraints per vertex: offsets (V+1,), the other endpoint and the constraint id of each entry."""
    ids = np.arange(len(pairs))
    first = np.concatenate([pairs[:, 0], pairs[:, 1]])
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    cid = np.concatenate([ids, ids])
    order = np.argsort(first, kind="stable")
    offsets = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(first, minlength=n_vertices), out=offsets[1:])
    return offsets, other[order], cid[order]


@dataclass(frozen=True)
class HarmonicConstraint:
    """Hard constraint B^T M (x - S x_low) = 0 (compliance 0), solved by M-orthogonal projection.

    `mass_basis` = M B (V, K) gives the residual; `correction_basis` = P_free B (B^T M P_free B)^{-1} (V, K)
    maps a residual to the smallest (in the M-norm) correction that zeroes it without moving pinned vertices.
    """
    mass_basis: np.ndarray
    correction_basis: np.ndarray


def harmonic_constraint(basis: np.ndarray, mass: np.ndarray, pinned: np.ndarray) -> HarmonicConstraint:
    """Build the projection for an M-orthonormal basis B (V, K), lumped mass (V,) and the pinned vertex ids."""
    free = np.ones(len(mass), dtype=bool)
    free[pinned] = False
    free_basis = basis * free[:, None]
    gram = basis.T @ (mass[:, None] * free_basis)
    cond = np.linalg.cond(gram)
    if not np.isfinite(cond) or cond > 1e8:
        raise ValueError(f"pinned vertices leave the harmonic constraint unsatisfiable (condition number {cond:.3g})")
    return HarmonicConstraint(mass_basis=mass[:, None] * basis,
                              correction_basis=np.linalg.solve(gram, free_basis.T).T)
