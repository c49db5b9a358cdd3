"""Fixtures of the model tests: a small grid mesh and its hierarchy (see model_meshes.py)."""
from __future__ import annotations

import pytest
import torch

from model_meshes import build_hierarchy, grid_mesh


@pytest.fixture(scope="session")
def grid():
    """A 6 x 7 grid (42 vertices) with a 5-level hierarchy of L = 7 tables."""
    vertices, faces = grid_mesh(6, 7)
    return vertices, faces, build_hierarchy(faces, len(vertices), 7, 5)


@pytest.fixture(autouse=True)
def _seeded():
    torch.manual_seed(0)
