"""The grid scene: a rectangle of cloth whose pins follow a rigid rod (one transform a frame)."""
from __future__ import annotations

import numpy as np

from geometry.rigid import apply_rigid
from scenes.grid import first_row_pins, grid_cloth, sway_driver
from scenes.scene import Pins, RodDriver, Scene


def grid_scene(settings: dict) -> Scene:
    """The grid scene of resolved settings (`mesh.generator: grid`); ValueError for settings it cannot build."""
    mesh = settings["mesh"]
    vertices, faces = grid_cloth(mesh["width"], mesh["height"], mesh["max_edge"], mesh["plane"], mesh["origin"])
    pin_rule = settings["drivers"]["pins"]
    pin_ids = first_row_pins(vertices, mesh["plane"], pin_rule) if settings["physics"]["pins"] else np.zeros(0, int)
    n_frames, dt = settings["frames"], settings["solver"]["dt"]
    motion = settings["drivers"]["motion"]
    if motion["type"] == "sway":
        rotation, translation = sway_driver(n_frames, dt, motion["amplitude"], motion["period"], motion["yaw"],
                                            motion["settle_frames"])
    else:
        rotation, translation = np.tile(np.eye(3), (n_frames, 1, 1)), np.zeros((n_frames, 3))
    pivot = vertices[pin_ids].mean(axis=0) if len(pin_ids) else vertices.mean(axis=0)
    transforms = np.tile(np.eye(4), (n_frames, 1, 1, 1))
    transforms[:, 0, :3, :3] = rotation
    transforms[:, 0, :3, 3] = pivot + translation - rotation @ pivot
    part = np.zeros(len(pin_ids), np.int64)   # one rigid group: the rod
    pins = Pins(ids=pin_ids, part=part, transforms=transforms,
                targets=apply_rigid(transforms[:, part], vertices[pin_ids]))
    return Scene(name=settings["scene"], generator=mesh["generator"], dt=dt, rest_vertices=vertices,
                 rest_faces=faces, pins=pins, rod=RodDriver(rotation=rotation, translation=translation, pivot=pivot))
