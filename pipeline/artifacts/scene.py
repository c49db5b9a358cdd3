"""scene.h5, written by the `scene` stage: the low-res rest mesh, its pins and what moves them — the rod of a
grid scene, or the animated mannequin of a garment scene (docs/artifacts.md, section "scene.h5").

The dataset paths are named here and nowhere else; the readers hand the later stages typed parts of the scene.
"""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import h5py
import numpy as np

from pipeline.artifacts.h5 import atomic_h5, open_artifact, read
from pipeline.errors import PipelineError
from scenes.motion import BodyState
from scenes.scene import Mannequin, Pins, Scene
from scenes.skeleton import TORSO, Skeleton

STAGE = "scene"

REST_VERTICES, REST_FACES = "rest/vertices", "rest/faces"
PIN_IDS, PIN_TARGETS, PIN_PART, PIN_TRANSFORMS = "pins/ids", "pins/targets", "pins/part", "pins/transforms"
ROD = "driver"
ROD_ROTATION, ROD_TRANSLATION, ROD_PIVOT = "driver/rotation", "driver/translation", "driver/pivot"
# The mannequin: skeleton, state and motion arrays are stored under the names of the fields they hold.
BODY = "body"
SKELETON_NAMES, SKELETON_PARENTS = "names", "parents"         # under body/
SKELETON_ARRAYS = ("joint_offsets", "frame_rotations", "capsule_a", "capsule_b", "radius_a", "radius_b",
                   "joint_lower", "joint_upper")             # under body/, float64
SKELETON_HEIGHT = "height"                                    # attr of body/
BODY_STATE = "body/state"
BODY_STATE_ARRAYS = ("rotation", "translation", "linear_velocity", "angular_velocity")      # float64
MOTION = "motion"
MOTION_ARRAYS = ("root_position", "root_velocity", "joint_angles", "joint_angle_rates")     # float64
MOTION_CLIP, MOTION_CLIP_NAMES = "motion/clip", "motion/clip_names"
CAPSULES = "capsules"
CAPSULE_A, CAPSULE_B = "capsules/a", "capsules/b"
CAPSULE_RADIUS_A, CAPSULE_RADIUS_B = "capsules/radius_a", "capsules/radius_b"
CAPSULE_VELOCITY_A, CAPSULE_VELOCITY_B = "capsules/velocity_a", "capsules/velocity_b"
POSE, TORSO_TRANSFORMS = "pose", "torso_transforms"
SKINNING_INFLUENCES, SKINNING_WEIGHTS = "skinning/influences", "skinning/weights"


def write_scene(path: str | os.PathLike, scene: Scene, settings: Mapping[str, Any]) -> None:
    """Write a scene; `settings` (the resolved scene settings it was built from) are its provenance `config`."""
    with atomic_h5(path, STAGE, settings) as f:
        # All datasets, then all attrs, each in a fixed order: the same scene gives the same file, byte for byte.
        for name, data in _datasets(scene).items():
            f.create_dataset(name, data=data)
        for name, values in _attrs(scene).items():
            f[name].attrs.update(values)
        f.attrs.update(scene=scene.name, frames=scene.n_frames, dt=scene.dt, generator=scene.generator)


def _datasets(scene: Scene) -> dict[str, np.ndarray]:
    """Every dataset of the scene, keyed by path, with its stored dtype."""
    pins = scene.pins
    data = {REST_VERTICES: scene.rest_vertices.astype(np.float64), REST_FACES: scene.rest_faces.astype(np.int32),
            PIN_IDS: pins.ids.astype(np.int32), PIN_TARGETS: pins.targets.astype(np.float32),
            PIN_PART: pins.part.astype(np.int32), PIN_TRANSFORMS: pins.transforms.astype(np.float64)}
    if scene.rod is not None:
        data.update({ROD_ROTATION: scene.rod.rotation.astype(np.float64),
                     ROD_TRANSLATION: scene.rod.translation.astype(np.float64),
                     ROD_PIVOT: scene.rod.pivot.astype(np.float64)})
    if scene.mannequin is not None:
        data.update(_mannequin_datasets(scene.mannequin))
    return data


def _mannequin_datasets(mannequin: Mannequin) -> dict[str, np.ndarray]:
    skel, state, clips, capsules = mannequin.skeleton, mannequin.state, mannequin.clips, mannequin.capsules
    return {
        f"{BODY}/{SKELETON_NAMES}": np.array(skel.names, dtype="S"),
        f"{BODY}/{SKELETON_PARENTS}": skel.parents.astype(np.int32),
        **{f"{BODY}/{name}": getattr(skel, name).astype(np.float64) for name in SKELETON_ARRAYS},
        **{f"{BODY_STATE}/{name}": getattr(state, name).astype(np.float64) for name in BODY_STATE_ARRAYS},
        **{f"{MOTION}/{name}": getattr(clips.motion, name).astype(np.float64) for name in MOTION_ARRAYS},
        MOTION_CLIP: clips.clip.astype(np.int32), MOTION_CLIP_NAMES: np.array(clips.names, dtype="S"),
        CAPSULE_A: capsules.a.astype(np.float32), CAPSULE_B: capsules.b.astype(np.float32),
        CAPSULE_RADIUS_A: capsules.radius_a.astype(np.float32), CAPSULE_RADIUS_B: capsules.radius_b.astype(np.float32),
        CAPSULE_VELOCITY_A: capsules.velocity_a.astype(np.float32),
        CAPSULE_VELOCITY_B: capsules.velocity_b.astype(np.float32),
        POSE: mannequin.pose.astype(np.float32), TORSO_TRANSFORMS: mannequin.torso_transforms.astype(np.float64),
        SKINNING_INFLUENCES: mannequin.skinning_influences.astype(np.int32),
        SKINNING_WEIGHTS: mannequin.skinning_weights.astype(np.float32),
    }


def _attrs(scene: Scene) -> dict[str, dict[str, Any]]:
    """The attrs of groups and datasets, keyed by path: what each means, in words."""
    attrs = {PIN_TARGETS: {"meaning": "frame f: pinned vertex positions at time f * dt"},
             PIN_TRANSFORMS: {"meaning": "frame f, group g: world-from-rest rigid transform moving the pins of "
                                         "group g (pins/part); carries pins to any subdivided mesh"}}
    if scene.rod is not None:
        attrs[ROD] = {"meaning": "pin target = rotation @ (rest - pivot) + pivot + translation"}
    if scene.mannequin is not None:
        attrs.update({
            BODY: {SKELETON_HEIGHT: scene.mannequin.skeleton.height, "torso": TORSO,
                   "angle_order": "R = Rz(az) Rx(ax) Ry(ay)"},
            MOTION: {"clips": ",".join(scene.mannequin.clips.names[1:]), "fps": 1.0 / scene.dt},
            TORSO_TRANSFORMS: {"meaning": "world-from-torso (pelvis) rigid transform per frame"},
            POSE: {"meaning": "per part: position (3) and rotation (4, xyzw) relative to the torso, world linear "
                              "and angular velocity in the torso frame (3 + 3)"}})
    return attrs


def read_rest_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The low-res rest mesh: vertices (V, 3) float64 and faces (F, 3) int64."""
    with open_artifact(path) as f:
        return read(f, REST_VERTICES, np.float64), read(f, REST_FACES, np.int64)


@dataclasses.dataclass(frozen=True, eq=False)
class SceneDrive:
    """What moves the cloth in the simulate stages, per frame: the pins and, when the body collides, the
    mannequin's capsules."""
    pins: Pins                         # ids and part int64, transforms and targets float64
    capsules: np.ndarray | None        # (N, P, 2, 3) float64 end points a, b of each capsule; None without collision
    capsule_radii: np.ndarray | None   # (P, 2) float64 radii at a and b


def read_scene_drive(path: str | os.PathLike, n_frames: int, body_collision: bool) -> SceneDrive:
    """The pins (checked to cover `n_frames` frames) and, if `body_collision`, the capsules (an error for a
    scene without a mannequin)."""
    with open_artifact(path) as f:
        ids, targets = read(f, PIN_IDS, np.int64), read(f, PIN_TARGETS, np.float64)
        part, transforms = read(f, PIN_PART, np.int64), read(f, PIN_TRANSFORMS, np.float64)
        if len(targets) != n_frames:
            raise PipelineError(f"{path}: has {len(targets)} frames of pin targets, settings ask for {n_frames}")
        capsules = radii = None
        if body_collision:
            if CAPSULES not in f:
                raise PipelineError(f"{path}: body_collision is on but the scene has no '{CAPSULES}' "
                                    f"(a grid scene has no mannequin)")
            capsules = np.stack([read(f, CAPSULE_A, np.float64), read(f, CAPSULE_B, np.float64)], axis=2)
            radii = np.stack([read(f, CAPSULE_RADIUS_A, np.float64), read(f, CAPSULE_RADIUS_B, np.float64)], axis=1)
    return SceneDrive(Pins(ids=ids, part=part, transforms=transforms, targets=targets), capsules, radii)


def read_clips(path: str | os.PathLike) -> tuple[np.ndarray, list[str]]:
    """The clip each frame belongs to, (N,) int64 indices into the clip names (`settle`, then the clips)."""
    with open_artifact(path) as f:
        return read(f, MOTION_CLIP, np.int64), [name.decode() for name in read(f, MOTION_CLIP_NAMES)]


def read_torso_transforms(path: str | os.PathLike, n_frames: int) -> np.ndarray:
    """World-from-torso rigid transforms (n_frames, 4, 4) float64, checked to be rigid; an error for a scene
    without a torso (a grid scene)."""
    with open_artifact(path) as f:
        if TORSO_TRANSFORMS not in f:
            raise PipelineError(f"{path}: --frame torso needs dataset '{TORSO_TRANSFORMS}' (F, 4, 4), "
                                f"world-from-torso per frame; this scene has no torso (use --frame world)")
        transforms = read(f, TORSO_TRANSFORMS, np.float64)
    if transforms.shape != (n_frames, 4, 4):
        raise PipelineError(f"{path}: '{TORSO_TRANSFORMS}' must be ({n_frames}, 4, 4), got {transforms.shape}")
    rotation = transforms[:, :3, :3]
    if not np.allclose(rotation @ rotation.transpose(0, 2, 1), np.eye(3), atol=1e-5):
        raise PipelineError(f"{path}: '{TORSO_TRANSFORMS}' rotations are not orthonormal")
    return transforms


def read_body(path: str | os.PathLike) -> tuple[Skeleton, BodyState] | None:
    """The mannequin's skeleton and its world state per frame, or None for a scene without one (a grid scene)."""
    with open_artifact(path) as f:
        if BODY not in f:
            return None
        skeleton = _skeleton_from_h5(f[BODY])
        state = BodyState(**{name: read(f, f"{BODY_STATE}/{name}", np.float64) for name in BODY_STATE_ARRAYS})
    return skeleton, state


def _skeleton_from_h5(group: h5py.Group) -> Skeleton:
    """The skeleton stored in scene.h5's `body` group."""
    return Skeleton(names=tuple(n.decode() for n in group[SKELETON_NAMES][()]),
                    parents=group[SKELETON_PARENTS][()].astype(np.int64),
                    **{name: np.asarray(group[name][()], dtype=np.float64) for name in SKELETON_ARRAYS},
                    height=float(group.attrs[SKELETON_HEIGHT]))
