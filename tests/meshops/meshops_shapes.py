"""The named test meshes of the operator tests (procedural surfaces from geometry.shapes, the pipeline's own
flag from scenes.flag_mesh) and their operators, each built once per session."""
from __future__ import annotations

import functools

import numpy as np

from geometry.shapes import cube_sphere, grid_patch, irregular_disk, pants, torus, two_triangles
from scenes.flag_mesh import flag_high_res


# The test meshes of issue #3 (and the pipeline's own flag), small enough to build all operators in about a second.
TEST_MESHES = {
    "flag": flag_high_res,
    "square": lambda: grid_patch(24, 20, 1.2, 1.0),
    "sphere": lambda: cube_sphere(10),
    "torus": lambda: torus(36, 14),
    "pants": lambda: pants(12),
    "irregular": lambda: irregular_disk(500),
    "two_triangles": two_triangles,
}


@functools.lru_cache(maxsize=None)
def mesh_of(name: str) -> tuple[np.ndarray, np.ndarray]:
    return TEST_MESHES[name]()


@functools.lru_cache(maxsize=None)
def operators_of(name: str) -> list:
    """Default operators (RC13, EC13, SP13, SPD13, 10 pooling steps) of a test mesh, built once per session."""
    from meshops import build_operators
    return build_operators(*mesh_of(name))
