"""Scene stage: the low-res rest mesh, its pinned vertices with their per-frame targets, and for garment scenes
the animated mannequin (skeleton, motion, collision capsules, pose vectors, torso frames, skinning weights).

CLI: `python -m pipeline.scene SETTINGS.json OUT.h5` (settings resolved by `python -m pipeline.config`).
docs/artifacts.md lists every dataset.
"""
from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np

from geometry.rigid import apply_rigid
from pipeline import cli
from pipeline.artifacts.h5 import atomic_h5
from pipeline.config import read_settings
from pipeline.errors import PipelineError
from pipeline.meshio import check_mesh
from scenes.mannequin import (TORSO, Skeleton, capsule_velocities, capsules_world, default_skeleton, quat_to_matrix,
                      rest_transforms)
from scenes.grid import first_row_pins, grid_cloth, sway_driver
from scenes.garments import make_garment
from scenes.motion import body_state, play_clips, pose_vectors
from scenes.skinning import rest_to_posed, skinning_weights


def build_scene(settings: dict) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """Every array of the scene keyed by dataset path, and attrs keyed by group or dataset path."""
    common = {"pins/targets": {"meaning": "frame f: pinned vertex positions at time f * dt"},
              "pins/transforms": {"meaning": "frame f, group g: world-from-rest rigid transform moving the pins "
                                             "of group g (pins/part); carries pins to any subdivided mesh"}}
    if settings["mesh"]["generator"] == "garment":
        skel = default_skeleton()
        return garment_scene(settings, skel), {**common, "body": {
            "height": skel.height, "torso": TORSO, "angle_order": "R = Rz(az) Rx(ax) Ry(ay)"},
            "motion": {"clips": ",".join(settings["drivers"]["mannequin"]["clips"]),
                       "fps": 1.0 / settings["solver"]["dt"]},
            "torso_transforms": {"meaning": "world-from-torso (pelvis) rigid transform per frame"},
            "pose": {"meaning": "per part: position (3) and rotation (4, xyzw) relative to the torso, world linear "
                                "and angular velocity in the torso frame (3 + 3)"}}
    return grid_scene(settings), {**common, "driver": {
        "meaning": "pin target = rotation @ (rest - pivot) + pivot + translation"}}


def grid_scene(settings: dict) -> dict[str, np.ndarray]:
    """A rectangle of cloth whose pins follow a rigid rod (one transform a frame)."""
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
    transforms = np.tile(np.eye(4), (n_frames, 1, 1, 1))
    transforms[:, 0, :3, :3] = rotation
    transforms[:, 0, :3, 3] = pivot + translation - rotation @ pivot
    part = np.zeros(len(pin_ids), np.int64)   # one rigid group: the rod
    return {
        "rest/vertices": vertices, "rest/faces": faces.astype(np.int32), "pins/ids": pin_ids.astype(np.int32),
        "pins/targets": apply_rigid(transforms[:, part], vertices[pin_ids]).astype(np.float32),
        "pins/part": part.astype(np.int32), "pins/transforms": transforms,
        "driver/rotation": rotation, "driver/translation": translation, "driver/pivot": pivot,
    }


def garment_scene(settings: dict, skel: Skeleton) -> dict[str, np.ndarray]:
    """A garment on the procedural mannequin playing the configured clips; its attachment vertices (waist band,
    shoulders) are pinned to the body part they follow."""
    mesh, drive = settings["mesh"], settings["drivers"]["mannequin"]
    where = f"scene '{settings['scene']}'"
    try:
        garment = make_garment(mesh["garment"], skel, mesh["max_edge"], mesh["seed"])
        clips = play_clips(drive["clips"], settings["frames"], drive["settle_frames"], drive["blend_frames"],
                           drive["seed"], fps=1.0 / settings["solver"]["dt"], skel=skel)
    except ValueError as err:
        raise PipelineError(f"{where}: {err}") from None
    check_mesh(where, garment.vertices, garment.faces)
    state = body_state(skel, clips.motion)
    a, b, radius_a, radius_b = capsules_world(skel, state.transforms)
    velocity_a, velocity_b = capsule_velocities(skel, state.transforms, state.velocities)
    rest = rest_transforms(skel)
    influences, weights = skinning_weights(skel, garment.vertices, garment.faces)
    pin_ids = garment.attachment if settings["physics"]["pins"] else np.zeros(0, np.int64)
    # An attachment vertex is rigidly bound to one part: it moves with that part's rest-to-posed transform.
    parts = garment.attachment_part[:len(pin_ids)]
    transforms = np.tile(np.eye(4), (clips.motion.n_frames, skel.n_parts, 1, 1))
    transforms[..., :3, :] = rest_to_posed(rest, state.transforms)
    targets = apply_rigid(transforms[:, parts], garment.vertices[pin_ids])
    torso = skel.index(TORSO)
    torso_transforms = np.tile(np.eye(4), (clips.motion.n_frames, 1, 1))
    torso_transforms[:, :3, :3] = quat_to_matrix(state.rotation[:, torso])
    torso_transforms[:, :3, 3] = state.translation[:, torso]
    m = clips.motion
    return {
        "rest/vertices": garment.vertices, "rest/faces": garment.faces.astype(np.int32),
        "pins/ids": pin_ids.astype(np.int32), "pins/targets": targets.astype(np.float32),
        "pins/part": parts.astype(np.int32), "pins/transforms": transforms,
        "body/names": np.array(skel.names, dtype="S"), "body/parents": skel.parents.astype(np.int32),
        "body/joint_offsets": skel.joint_offsets, "body/frame_rotations": skel.frame_rotations,
        "body/capsule_a": skel.capsule_a, "body/capsule_b": skel.capsule_b,
        "body/radius_a": skel.radius_a, "body/radius_b": skel.radius_b,
        "body/joint_lower": skel.joint_lower, "body/joint_upper": skel.joint_upper,
        "body/state/rotation": state.rotation, "body/state/translation": state.translation,
        "body/state/linear_velocity": state.linear_velocity, "body/state/angular_velocity": state.angular_velocity,
        "motion/root_position": m.root_position, "motion/root_velocity": m.root_velocity,
        "motion/joint_angles": m.joint_angles, "motion/joint_angle_rates": m.joint_angle_rates,
        "motion/clip": clips.clip.astype(np.int32), "motion/clip_names": np.array(clips.names, dtype="S"),
        "capsules/a": a.astype(np.float32), "capsules/b": b.astype(np.float32),
        "capsules/radius_a": radius_a[0].astype(np.float32), "capsules/radius_b": radius_b[0].astype(np.float32),
        "capsules/velocity_a": velocity_a.astype(np.float32), "capsules/velocity_b": velocity_b.astype(np.float32),
        "pose": pose_vectors(skel, m).astype(np.float32), "torso_transforms": torso_transforms,
        "skinning/influences": influences.astype(np.int32), "skinning/weights": weights.astype(np.float32),
    }


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.scene", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON)")
    parser.add_argument("out", help="scene.h5 to write")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings)
    arrays, attrs = build_scene(settings)
    with atomic_h5(args.out, "scene", settings) as f:
        for name, data in arrays.items():
            f.create_dataset(name, data=data)
        for name, values in attrs.items():
            f[name].attrs.update(values)
        f.attrs.update(scene=settings["scene"], frames=settings["frames"], dt=settings["solver"]["dt"],
                       generator=settings["mesh"]["generator"])


if __name__ == "__main__":
    cli.run(main)
