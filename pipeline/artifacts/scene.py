"""scene.h5, written by the `scene` stage: what every sequence of a scene shares (results/<scene>/scene.h5: the
low-res rest mesh, its pinned vertices, a garment scene's skeleton and skinning), and one sequence
(results/<scene>/sequences/<name>/scene.h5: all of that, plus the pins' targets and what moves them — the rod of
a grid scene, or the animated mannequin of a garment scene) (docs/artifacts.md, section "scene.h5").

The dataset paths are named here and nowhere else; the readers hand the later stages typed parts of the scene.
"""
from __future__ import annotations

import dataclasses
import json
import os
from typing import Any, Mapping

import h5py
import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import (SOURCE_MESH, atomic_h5, mesh_fingerprint, open_artifact, read, read_indices,
                              write_dropped)
from scenes.motion import BodyState
from scenes.program import ProgramClip
from scenes.scene import Mannequin, Pins, Scene, SceneRest
from scenes.sequences import HELD_OUT, TRAIN, sequence_role
from scenes.skeleton import TORSO, Skeleton

STAGE = "scene"

REST_VERTICES, REST_FACES = "rest/vertices", "rest/faces"
PIN_IDS, PIN_TARGETS, PIN_PART, PIN_TRANSFORMS = "pins/ids", "pins/targets", "pins/part", "pins/transforms"
ROD = "driver"
LIBRARY_WINDOW = "library_window"      # root attr: a motion library window's file, subject, category, ... (JSON)
SETTLED_START = "settled_start"        # root attr, true: the cloth starts where the scene's settle runs end
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
PROGRAM = "motion/program"
PROGRAM_ARRAYS = {"start": np.int32, "end": np.int32, "fade_in": np.int32, "fade_out": np.int32,
                  "speed": np.float64, "amplitude": np.float64, "phase": np.float64, "seed": np.int64}
CAPSULES = "capsules"
CAPSULE_A, CAPSULE_B = "capsules/a", "capsules/b"
CAPSULE_RADIUS_A, CAPSULE_RADIUS_B = "capsules/radius_a", "capsules/radius_b"
CAPSULE_VELOCITY_A, CAPSULE_VELOCITY_B = "capsules/velocity_a", "capsules/velocity_b"
POSE, TORSO_TRANSFORMS = "pose", "torso_transforms"
SKINNING_INFLUENCES, SKINNING_WEIGHTS = "skinning/influences", "skinning/weights"
# The mannequin as the learning stages read it, frame by frame (dataset.h5 carries a copy of these per frame):
MANNEQUIN_PER_FRAME = (*(f"{BODY_STATE}/{name}" for name in BODY_STATE_ARRAYS), CAPSULE_A, CAPSULE_B,
                       CAPSULE_VELOCITY_A, CAPSULE_VELOCITY_B, POSE, TORSO_TRANSFORMS)
MANNEQUIN_CONSTANT = (f"{BODY}/{SKELETON_NAMES}", f"{BODY}/{SKELETON_PARENTS}",
                      *(f"{BODY}/{name}" for name in SKELETON_ARRAYS), CAPSULE_RADIUS_A, CAPSULE_RADIUS_B)


def write_scene_rest(path: str | os.PathLike, rest: SceneRest, settings: Mapping[str, Any]) -> None:
    """Write what every sequence of a scene shares; `settings` (the resolved scene settings) are its `config`."""
    with atomic_h5(path, STAGE, settings) as f:
        _write(f, _rest_datasets(rest), _rest_attrs(rest))
        f.attrs.update(scene=rest.name, generator=rest.generator, **_source_mesh(rest))


def write_scene(path: str | os.PathLike, scene: Scene, settings: Mapping[str, Any]) -> None:
    """Write one sequence of a scene; `settings` (the resolved scene settings it was built from) are its
    provenance `config`."""
    with atomic_h5(path, STAGE, settings) as f:
        _write(f, {**_rest_datasets(scene.rest), **_sequence_datasets(scene)},
               {**_rest_attrs(scene.rest), **_sequence_attrs(scene)})
        f.attrs.update(scene=scene.rest.name, generator=scene.rest.generator, **_source_mesh(scene.rest),
                       sequence=scene.sequence,
                       role=sequence_role(scene.sequence), frames=scene.n_frames, dt=scene.dt)
        if scene.library_window is not None:
            f.attrs[LIBRARY_WINDOW] = json.dumps(scene.library_window, sort_keys=True)
        if scene.settled_start:
            f.attrs[SETTLED_START] = True


def write_dropped_scene(path: str | os.PathLike, rest: SceneRest, sequence: str, reason: str,
                        library_window: dict | None, settings: Mapping[str, Any]) -> None:
    """The scene file of a sequence that cannot be made (a library window whose clip cannot be played): what
    identifies it, and why (pipeline.core.h5.write_dropped); the simulate and dataset stages pass it over."""
    write_dropped(path, STAGE, settings, reason, {
        "scene": rest.name, "generator": rest.generator, **_source_mesh(rest), "sequence": sequence,
        "role": sequence_role(sequence),
        **({LIBRARY_WINDOW: json.dumps(library_window, sort_keys=True)} if library_window else {})})


def read_library_window(path: str | os.PathLike) -> dict | None:
    """The library window a sequence's scene file plays (scenes.library.LibraryWindow.describe), or None."""
    with open_artifact(path) as f:
        value = f.attrs.get(LIBRARY_WINDOW)
    try:
        window = None if value is None else json.loads(value)
    except (TypeError, ValueError):
        raise PipelineError(f"{path}: attr '{LIBRARY_WINDOW}' is not JSON") from None
    if window is not None and not (isinstance(window, dict) and all(isinstance(window.get(k), str) for k in
                                                                     ("file", "subject", "category"))):
        raise PipelineError(f"{path}: attr '{LIBRARY_WINDOW}' lacks its file, subject and category")
    return window


def _source_mesh(rest: SceneRest) -> dict[str, str]:
    """The root attr naming the rest mesh that subdiv.h5 and the runs derive from (docs/artifacts.md)."""
    return {SOURCE_MESH: mesh_fingerprint(rest.vertices, rest.faces)}


def _write(f: h5py.File, datasets: dict[str, np.ndarray], attrs: dict[str, dict[str, Any]]) -> None:
    # All datasets, then all attrs, each in a fixed order: the same scene gives the same file, byte for byte.
    for name, data in datasets.items():
        f.create_dataset(name, data=data)
    for name, values in attrs.items():
        f[name].attrs.update(values)


def _rest_datasets(rest: SceneRest) -> dict[str, np.ndarray]:
    """What every sequence shares, keyed by path, with its stored dtype."""
    data = {REST_VERTICES: rest.vertices.astype(np.float64), REST_FACES: rest.faces.astype(np.int32),
            PIN_IDS: rest.pin_ids.astype(np.int32), PIN_PART: rest.pin_part.astype(np.int32)}
    if rest.skeleton is not None:
        skel = rest.skeleton
        data.update({f"{BODY}/{SKELETON_NAMES}": np.array(skel.names, dtype="S"),
                     f"{BODY}/{SKELETON_PARENTS}": skel.parents.astype(np.int32),
                     **{f"{BODY}/{name}": getattr(skel, name).astype(np.float64) for name in SKELETON_ARRAYS},
                     SKINNING_INFLUENCES: rest.skinning_influences.astype(np.int32),
                     SKINNING_WEIGHTS: rest.skinning_weights.astype(np.float32)})
    return data


def _sequence_datasets(scene: Scene) -> dict[str, np.ndarray]:
    """A sequence's per-frame datasets, keyed by path, with their stored dtypes."""
    pins = scene.pins
    data = {PIN_TARGETS: pins.targets.astype(np.float32), PIN_TRANSFORMS: pins.transforms.astype(np.float64)}
    if scene.rod is not None:
        data.update({ROD_ROTATION: scene.rod.rotation.astype(np.float64),
                     ROD_TRANSLATION: scene.rod.translation.astype(np.float64),
                     ROD_PIVOT: scene.rod.pivot.astype(np.float64)})
    if scene.mannequin is not None:
        data.update(_mannequin_datasets(scene.mannequin))
    return data


def _mannequin_datasets(mannequin: Mannequin) -> dict[str, np.ndarray]:
    state, clips, capsules = mannequin.state, mannequin.clips, mannequin.capsules
    return {
        **{f"{BODY_STATE}/{name}": getattr(state, name).astype(np.float64) for name in BODY_STATE_ARRAYS},
        **{f"{MOTION}/{name}": getattr(clips.motion, name).astype(np.float64) for name in MOTION_ARRAYS},
        MOTION_CLIP: clips.clip.astype(np.int32), MOTION_CLIP_NAMES: np.array(clips.names, dtype="S"),
        **_program_datasets(mannequin.program),
        CAPSULE_A: capsules.a.astype(np.float32), CAPSULE_B: capsules.b.astype(np.float32),
        CAPSULE_RADIUS_A: capsules.radius_a.astype(np.float32), CAPSULE_RADIUS_B: capsules.radius_b.astype(np.float32),
        CAPSULE_VELOCITY_A: capsules.velocity_a.astype(np.float32),
        CAPSULE_VELOCITY_B: capsules.velocity_b.astype(np.float32),
        POSE: mannequin.pose.astype(np.float32), TORSO_TRANSFORMS: mannequin.torso_transforms.astype(np.float64),
    }


def _program_datasets(program: tuple[ProgramClip, ...]) -> dict[str, np.ndarray]:
    """How a training sequence's clips were drawn, one entry per clip (none for a sequence without a program)."""
    if not program:
        return {}
    return {f"{PROGRAM}/{name}": np.array([getattr(clip, name) for clip in program], dtype=dtype)
            for name, dtype in PROGRAM_ARRAYS.items()}


def _rest_attrs(rest: SceneRest) -> dict[str, dict[str, Any]]:
    if rest.skeleton is None:
        return {}
    return {BODY: {SKELETON_HEIGHT: rest.skeleton.height, "torso": TORSO, "angle_order": "R = Rz(az) Rx(ax) Ry(ay)"}}


def _sequence_attrs(scene: Scene) -> dict[str, dict[str, Any]]:
    """The attrs of a sequence's groups and datasets, keyed by path: what each means, in words."""
    attrs = {PIN_TARGETS: {"meaning": "frame f: pinned vertex positions at time f * dt"},
             PIN_TRANSFORMS: {"meaning": "frame f, group g: world-from-rest rigid transform moving the pins of "
                                         "group g (pins/part); carries pins to any subdivided mesh"}}
    if scene.rod is not None:
        attrs[ROD] = {"meaning": "pin target = rotation @ (rest - pivot) + pivot + translation"}
    if scene.mannequin is not None:
        attrs.update({
            MOTION: {"clips": ",".join(scene.mannequin.clips.names[1:]), "fps": 1.0 / scene.dt},
            TORSO_TRANSFORMS: {"meaning": "world-from-torso (pelvis) rigid transform per frame"},
            POSE: {"meaning": "per part: position (3) and rotation (4, xyzw) relative to the torso, world linear "
                              "and angular velocity in the torso frame (3 + 3)"}})
        if scene.mannequin.program:
            attrs[PROGRAM] = {"meaning": "one entry per clip of motion/clip_names[1:]: frames where its fade-in "
                                         "starts and its fade-out ends, fade lengths (frames; fade_out 0: plays "
                                         "to the end), speed, amplitude, phase (s) and seed of its curves"}
    return attrs


def read_rest_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """The low-res rest mesh: vertices (V, 3) float64 and faces (F, 3) int64, indices checked against V."""
    with open_artifact(path) as f:
        vertices = read(f, REST_VERTICES, np.float64)
        return vertices, read_indices(f, REST_FACES, len(vertices), shape=(None, 3))


@dataclasses.dataclass(frozen=True, eq=False)
class SceneDrive:
    """What moves the cloth in the simulate stages, per frame: the pins and, when the body collides, the
    mannequin's capsules."""
    pins: Pins                         # ids and part int64, transforms and targets float64
    capsules: np.ndarray | None        # (N, P, 2, 3) float64 end points a, b of each capsule; None without collision
    capsule_radii: np.ndarray | None   # (P, 2) float64 radii at a and b
    settled_start: bool = False        # the cloth starts settled (Scene.settled_start), not at its rest shape

    @property
    def n_frames(self) -> int:
        return len(self.pins.targets)


def read_scene_drive(path: str | os.PathLike, body_collision: bool) -> SceneDrive:
    """A sequence's pins (ids checked against the rest mesh, targets and transforms against each other) and, if
    `body_collision`, the capsules (an error for a scene without a mannequin)."""
    with open_artifact(path) as f:
        if PIN_TARGETS not in f:
            raise PipelineError(f"{path}: no '{PIN_TARGETS}': not the scene of a sequence "
                                f"(results/<scene>/sequences/<name>/scene.h5)")
        n_vertices = len(read(f, REST_VERTICES))
        transforms, targets = read(f, PIN_TRANSFORMS, np.float64), read(f, PIN_TARGETS, np.float64)
        ids = read_indices(f, PIN_IDS, n_vertices, shape=(None,))
        if transforms.ndim != 4 or transforms.shape[2:] != (4, 4) or targets.shape != (len(transforms), len(ids), 3):
            raise PipelineError(f"{path}: '{PIN_TRANSFORMS}' {transforms.shape} and '{PIN_TARGETS}' "
                                f"{targets.shape} must be (N, G, 4, 4) and (N, {len(ids)}, 3)")
        part = read_indices(f, PIN_PART, transforms.shape[1], shape=(len(ids),))
        capsules = radii = None
        if body_collision:
            if CAPSULES not in f:
                raise PipelineError(f"{path}: body_collision is on but the scene has no '{CAPSULES}' "
                                    f"(a grid scene has no mannequin)")
            capsules = np.stack([read(f, CAPSULE_A, np.float64), read(f, CAPSULE_B, np.float64)], axis=2)
            radii = np.stack([read(f, CAPSULE_RADIUS_A, np.float64), read(f, CAPSULE_RADIUS_B, np.float64)], axis=1)
            if len(capsules) != len(targets):
                raise PipelineError(f"{path}: {len(capsules)} frames of capsules but {len(targets)} of pin targets")
        settled_start = bool(f.attrs.get(SETTLED_START, False))
    return SceneDrive(Pins(ids=ids, part=part, transforms=transforms, targets=targets), capsules, radii,
                      settled_start)


@dataclasses.dataclass(frozen=True, eq=False)
class SequenceInfo:
    """Which sequence a scene file holds, and the clip each of its frames belongs to."""
    name: str
    role: str                      # train or held_out (scenes.sequences)
    n_frames: int
    clip: np.ndarray | None        # (N,) int64 index into clip_names; None for a scene without a mannequin
    clip_names: tuple[str, ...]    # settle, then the clips in playing order; () without a mannequin

    @property
    def settle_frames(self) -> int:
        """Frames before the first clip: at rest, the same in every sequence of the scene."""
        return 0 if self.clip is None else int(np.argmax(np.append(self.clip, 1) > 0))


def read_sequence(path: str | os.PathLike) -> SequenceInfo:
    """The sequence a scene file holds (an error for the shared scene.h5, which holds none)."""
    with open_artifact(path) as f:
        if "sequence" not in f.attrs or PIN_TARGETS not in f:
            raise PipelineError(f"{path}: not the scene of a sequence (no 'sequence' attr; "
                                f"results/<scene>/sequences/<name>/scene.h5 holds one)")
        name, role, n_frames = str(f.attrs["sequence"]), str(f.attrs.get("role")), len(f[PIN_TARGETS])
        if role not in (TRAIN, HELD_OUT):
            raise PipelineError(f"{path}: attr 'role' is '{role}', not '{TRAIN}' or '{HELD_OUT}'")
        if MOTION_CLIP not in f:
            return SequenceInfo(name, role, n_frames, None, ())
        names = tuple(n.decode() for n in read(f, MOTION_CLIP_NAMES))
        clip = read_indices(f, MOTION_CLIP, len(names), shape=(n_frames,))
    return SequenceInfo(name, role, n_frames, clip, names)


@dataclasses.dataclass(frozen=True, eq=False)
class MannequinFrames:
    """A sequence's mannequin as scene.h5 stores it, each dataset and attr set keyed by its path here."""
    per_frame: dict[str, np.ndarray]         # MANNEQUIN_PER_FRAME, from some frame on
    constant: dict[str, np.ndarray]          # MANNEQUIN_CONSTANT
    attrs: dict[str, dict[str, Any]]         # attrs of the `body` group


def read_mannequin_frames(path: str | os.PathLike, first: int) -> MannequinFrames | None:
    """A sequence's mannequin from frame `first` on (None for a scene without one). The dataset stage copies it
    under the same names, so readers of scene.h5's body (read_body, read_torso_transforms) read it there too."""
    with open_artifact(path) as f:
        if BODY_STATE not in f:
            return None
        return MannequinFrames(per_frame={name: read(f, name)[first:] for name in MANNEQUIN_PER_FRAME},
                               constant={name: read(f, name) for name in MANNEQUIN_CONSTANT},
                               attrs={BODY: dict(f[BODY].attrs)})


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
        skeleton = _skeleton_from_h5(f)
        state = BodyState(**{name: read(f, f"{BODY_STATE}/{name}", np.float64) for name in BODY_STATE_ARRAYS})
    return skeleton, state


def read_skinning(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray] | None:
    """The rest mesh's skinning: influences (V, K) int64 part indices and weights (V, K) float64 (rows summing
    to 1), checked against the rest mesh and the skeleton; None for a scene without a mannequin."""
    with open_artifact(path) as f:
        if SKINNING_WEIGHTS not in f:
            return None
        n_vertices, n_parts = len(read(f, REST_VERTICES)), len(read(f, f"{BODY}/{SKELETON_NAMES}"))
        weights = read(f, SKINNING_WEIGHTS, np.float64)
        influences = read_indices(f, SKINNING_INFLUENCES, n_parts, shape=weights.shape)
    if weights.ndim != 2 or len(weights) != n_vertices or np.any(weights < 0) \
            or not np.allclose(weights.sum(axis=1), 1.0, atol=1e-4):
        raise PipelineError(f"{path}: '{SKINNING_WEIGHTS}' must be ({n_vertices}, K), non-negative, rows summing "
                            f"to 1")
    return influences, weights


def _skeleton_from_h5(f: h5py.File) -> Skeleton:
    """The skeleton stored in scene.h5's `body` group; a joint's parent is another joint, or -1 for the root."""
    group = f[BODY]
    names = tuple(n.decode() for n in read(f, f"{BODY}/{SKELETON_NAMES}"))
    return Skeleton(names=names,
                    parents=read_indices(f, f"{BODY}/{SKELETON_PARENTS}", len(names), shape=(len(names),), lower=-1),
                    **{name: read(f, f"{BODY}/{name}", np.float64) for name in SKELETON_ARRAYS},
                    height=float(group.attrs[SKELETON_HEIGHT]))
