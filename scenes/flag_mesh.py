"""The flag scene's cloth as the pipeline builds it (workflow_config.yaml's `flag`: a 1 x 1 banner hanging in
the xy-plane, top edge at y = 1.5), for tests and benchmarks that need a real scene mesh without running the
scene and subdivide stages."""
from __future__ import annotations

import numpy as np

from geometry.loop_subdivision import loop_subdivide
from geometry.shapes import checked_mesh
from scenes.grid import grid_cloth


def flag_cloth(max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """The low-res flag: a grid cloth with alternating diagonals (valence 4 and 8 vertices)."""
    return grid_cloth(1.0, 1.0, max_edge, plane="xy", origin=(-0.5, 1.5, 0.0))


def flag_high_res(max_edge: float = 0.12) -> tuple[np.ndarray, np.ndarray]:
    """The flag's high-res mesh: the low-res flag Loop-subdivided twice (CPU profile: max edge 0.12, ~2.4k
    vertices)."""
    low, low_faces = flag_cloth(max_edge)
    subdivision, faces = loop_subdivide(low, low_faces, levels=2)
    return checked_mesh(subdivision @ low, faces)
