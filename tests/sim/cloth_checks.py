"""Measures of a cloth the solver tests share (imported by package path: tests.sim.cloth_checks)."""
import numpy as np

from geometry.mesh import unique_edges


def edge_ratios(x, rest, faces):
    """Each edge's length at positions x over its rest length."""
    e = unique_edges(faces)
    return np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)
