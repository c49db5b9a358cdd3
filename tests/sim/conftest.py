"""Fixtures the solver tests share."""
import pytest

from scenes.grid import first_row_pins, grid_cloth


@pytest.fixture(scope="module")
def hanging_cloth():
    """A 0.6 m square hanging in the xy plane (10 x 10 vertices), its top edge pinned: rest, faces, pins."""
    vertices, faces = grid_cloth(0.6, 0.6, 0.1, plane="xy", origin=(0, 1, 0))
    return vertices, faces, first_row_pins(vertices, "xy", "top_edge")
