"""The grid scene: a rectangle of cloth whose pins follow a rigid rod (one transform a frame). It has one
sequence, train_000: the rod's motion has nothing to vary."""
from __future__ import annotations

import numpy as np

from geometry.mesh import weld_vertices
from geometry.rigid import apply_rigid
from scenes.grid import first_row_pins, grid_cloth, sway_driver
from scenes.scene import Pins, RodDriver, Scene, SceneRest
from scenes.sequences import TRAIN, sequence_name

ONLY_SEQUENCE = sequence_name(TRAIN, 0)


def grid_rest(settings: dict) -> SceneRest:
    """The grid and its pins (`mesh.generator: grid`); ValueError for settings it cannot build. `mesh.weld`
    > 0 merges vertices that close before the pins are chosen, as for any generator (a grid has no seams, so only
    a tolerance near its edge length changes it)."""
    mesh = settings["mesh"]
    vertices, faces = grid_cloth(mesh["width"], mesh["height"], mesh["max_edge"], mesh["plane"], mesh["origin"])
    if mesh["weld"] > 0:
        vertices, faces, _ = weld_vertices(vertices, faces, mesh["weld"])
    pin_rule = settings["drivers"]["pins"]
    pin_ids = first_row_pins(vertices, mesh["plane"], pin_rule) if settings["physics"]["pins"] else np.zeros(0, int)
    return SceneRest(name=settings["scene"], generator=mesh["generator"], vertices=vertices, faces=faces,
                     pin_ids=np.asarray(pin_ids, np.int64), pin_part=np.zeros(len(pin_ids), np.int64))


def grid_scene(settings: dict, rest: SceneRest, sequence: str) -> Scene:
    """The grid's one sequence: its pins moved by the rod of `drivers.motion`."""
    if sequence != ONLY_SEQUENCE:
        raise ValueError(f"a grid scene has one sequence, {ONLY_SEQUENCE}; got '{sequence}'")
    n_frames, dt = settings["frames"], settings["solver"]["dt"]
    motion = settings["drivers"]["motion"]
    if motion["type"] == "sway":
        rotation, translation = sway_driver(n_frames, dt, motion["amplitude"], motion["period"], motion["yaw"],
                                            motion["settle_frames"])
    else:
        rotation, translation = np.tile(np.eye(3), (n_frames, 1, 1)), np.zeros((n_frames, 3))
    pin_ids = rest.pin_ids
    pivot = rest.vertices[pin_ids].mean(axis=0) if len(pin_ids) else rest.vertices.mean(axis=0)
    transforms = np.tile(np.eye(4), (n_frames, 1, 1, 1))
    transforms[:, 0, :3, :3] = rotation
    transforms[:, 0, :3, 3] = pivot + translation - rotation @ pivot
    pins = Pins(ids=pin_ids, part=rest.pin_part, transforms=transforms,
                targets=apply_rigid(transforms[:, rest.pin_part], rest.vertices[pin_ids]))
    return Scene(rest=rest, sequence=sequence, dt=dt, pins=pins,
                 rod=RodDriver(rotation=rotation, translation=translation, pivot=pivot))
