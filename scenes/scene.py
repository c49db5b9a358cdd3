"""One scene as typed objects: what every sequence of a scene shares (the cloth's rest mesh, which vertices are
pinned to which rigid group, the mannequin's skeleton and the garment's skinning), and one sequence: the pins'
targets and what moves them, for every frame.

Every scene has a rest mesh and pins; each scene kind adds its own driver: a grid scene the rigid rod its pins
hang from, a garment scene the animated mannequin. `scenes.registry` makes them from resolved settings
(`build_rest`, and `build_scene` for one sequence, scenes.sequences); the scene stage writes them to scene.h5
(docs/artifacts.md). Arrays keep their natural precision here (float64 positions, int64 indices); the artifact
writer chooses the stored dtypes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.motion import BodyState, ClipSequence
from scenes.program import ProgramClip
from scenes.skeleton import Skeleton


@dataclass(frozen=True, eq=False)
class Pins:
    """Kinematic vertices: each pin moves rigidly with one group, so any mesh refined from the rest mesh (the
    subdivided high-res one) can move its own copies of the pins with the same transforms."""
    ids: np.ndarray         # (P,) int64 pinned vertex ids; empty when physics.pins is off
    part: np.ndarray        # (P,) int64 rigid group each pin follows (a body part, or 0: the rod)
    transforms: np.ndarray  # (N, G, 4, 4) float64 world-from-rest rigid transform of each group per frame
    targets: np.ndarray     # (N, P, 3) float64 pin positions per frame: transforms[:, part] applied to rest


@dataclass(frozen=True, eq=False)
class RodDriver:
    """The rigid rod a grid scene's pins hang from: pin target = rotation (rest - pivot) + pivot + translation."""
    rotation: np.ndarray     # (N, 3, 3)
    translation: np.ndarray  # (N, 3)
    pivot: np.ndarray        # (3,) centroid of the pins at rest (of all vertices without pins)


@dataclass(frozen=True, eq=False)
class PosedCapsules:
    """The mannequin's collision capsules in world space per frame, with the velocities of their end points."""
    a: np.ndarray           # (N, P, 3)
    b: np.ndarray           # (N, P, 3)
    radius_a: np.ndarray    # (P,)
    radius_b: np.ndarray    # (P,)
    velocity_a: np.ndarray  # (N, P, 3)
    velocity_b: np.ndarray  # (N, P, 3)


@dataclass(frozen=True, eq=False)
class Mannequin:
    """The animated mannequin a garment scene's cloth is worn by in one sequence, and what the learning stages
    derive from it."""
    clips: ClipSequence            # the motion played, and which clip each frame belongs to
    program: tuple[ProgramClip, ...]   # how a training sequence's clips were drawn (scenes.program); () otherwise
    state: BodyState               # world transforms and velocities of every part per frame
    capsules: PosedCapsules
    pose: np.ndarray               # (N, 13 P) Pose to Cloth input per frame (scenes.motion.pose_vectors)
    torso_transforms: np.ndarray   # (N, 4, 4) world-from-torso rigid transform per frame


@dataclass(frozen=True, eq=False)
class SceneRest:
    """What every sequence of a scene shares; `generator` names the kind (the registry's key)."""
    name: str
    generator: str
    vertices: np.ndarray           # (V, 3) float64 rest mesh
    faces: np.ndarray              # (F, 3) int64
    pin_ids: np.ndarray            # (P,) int64 pinned vertex ids; empty when physics.pins is off
    pin_part: np.ndarray           # (P,) int64 rigid group each pin follows (a body part, or 0: the rod)
    skeleton: Skeleton | None = None               # garment scenes: the mannequin
    skinning_influences: np.ndarray | None = None  # garment scenes: (V, K) int64 parts each rest vertex follows
    skinning_weights: np.ndarray | None = None     # (V, K) float64, rows sum to 1


@dataclass(frozen=True, eq=False)
class Scene:
    """One sequence (scenes.sequences) of a scene: `n_frames` frames at time step `dt`."""
    rest: SceneRest
    sequence: str                  # its name, e.g. train_000
    dt: float
    pins: Pins
    rod: RodDriver | None = None          # grid scenes
    mannequin: Mannequin | None = None    # garment scenes
    library_window: dict | None = None    # a motion library's window: file, subject, category, description,
                                          # start and end (seconds of its motion), frame_time (scenes.library)
    settled_start: bool = False           # frame 0 is the garment's settled cloth (the last frame of its settle
                                          # sequence's runs, scenes.sequences.SETTLE), not its rest shape

    @property
    def n_frames(self) -> int:
        return len(self.pins.transforms)
