"""Scene stage: the low-res rest mesh, its pinned vertices and the per-frame kinematic pin targets.

CLI: `python -m pipeline.scene SETTINGS.json OUT.h5` (settings resolved by `python -m pipeline.config`).
"""
from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np

from pipeline import cli
from pipeline.artifacts import atomic_h5
from pipeline.config import read_settings
from pipeline.meshio import check_mesh
from sim.cloth import apply_rigid, first_row_pins, grid_cloth, sway_driver


def build_scene(settings: dict) -> dict[str, np.ndarray]:
    """Arrays of a scene: rest mesh, pin ids, and the rigid driver that moves the pins (one transform a frame)."""
    mesh = settings["mesh"]
    vertices, faces = grid_cloth(mesh["width"], mesh["height"], mesh["max_edge"], mesh["plane"], mesh["origin"])
    check_mesh(f"scene '{settings['scene']}'", vertices, faces)
    pins = settings["drivers"]["pins"]
    pin_ids = first_row_pins(vertices, mesh["plane"], pins) if settings["physics"]["pins"] else np.zeros(0, int)
    n_frames, dt = settings["frames"], settings["solver"]["dt"]
    motion = settings["drivers"]["motion"]
    if motion["type"] == "sway":
        rotation, translation = sway_driver(n_frames, dt, motion["amplitude"], motion["period"], motion["yaw"],
                                            motion["settle_frames"])
    else:
        rotation, translation = np.tile(np.eye(3), (n_frames, 1, 1)), np.zeros((n_frames, 3))
    pivot = vertices[pin_ids].mean(axis=0) if len(pin_ids) else vertices.mean(axis=0)
    return {
        "rest/vertices": vertices, "rest/faces": faces.astype(np.int32), "pins/ids": pin_ids.astype(np.int32),
        "pins/targets": apply_rigid(rotation, translation, pivot, vertices[pin_ids]).astype(np.float32),
        "driver/rotation": rotation, "driver/translation": translation, "driver/pivot": pivot,
    }


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON)")
    parser.add_argument("out", help="scene.h5 to write")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings)
    arrays = build_scene(settings)
    with atomic_h5(args.out, "scene", settings) as f:
        for name, data in arrays.items():
            f.create_dataset(name, data=data)
        f.attrs["scene"] = settings["scene"]
        f.attrs["frames"] = settings["frames"]
        f.attrs["dt"] = settings["solver"]["dt"]
        f["pins/targets"].attrs["meaning"] = "frame f: pinned vertex positions at time f * dt"
        f["driver"].attrs["meaning"] = "pin target = rotation @ (rest - pivot) + pivot + translation"


if __name__ == "__main__":
    cli.run(main)
