"""The garment scene: a garment on the procedural mannequin, its attachment vertices (waist band, shoulders)
pinned to the body part they follow. Every sequence wears the same garment; a training sequence plays a seeded
motion program over the training clips, a held-out sequence its one test clip, a motion library's window its
window the paper's way (scenes.sequences, scenes.library, scenes.motion.play_window), starting from the cloth its
settle sequence left at rest."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geometry.rigid import apply_rigid
from geometry.rotations import quat_to_matrix
from scenes.bvh import read_bvh
from scenes.capsules import capsule_velocities, capsules_world, limbs_through_each_other, self_collision_pairs
from scenes.garments import Garment, make_garment
from scenes.kinematics import rest_transforms
from scenes.library import LibraryWindow, UnusableWindow, find_window
from scenes.motion import (BodyState, ClipSequence, Motion, at_rest, body_state, play_clips, play_window,
                           pose_vectors)
from scenes.program import plan_program, play_program
from scenes.scene import Mannequin, Pins, PosedCapsules, Scene, SceneRest
from scenes.retarget import retarget
from scenes.sequences import SETTLE, TRAIN, is_window_name, parse_sequence_name, sequence_clips, window_key
from scenes.skeleton import TORSO, Skeleton, default_skeleton
from scenes.skinning import rest_to_posed, skinning_weights


def garment_rest(settings: dict, dressed: Garment | None = None) -> SceneRest:
    """The garment at rest on the mannequin, its attachment pins and skinning; ValueError for settings it cannot
    build. `mesh.generator: garment` makes it (scenes.garments; a mesh too coarse for the garment is an error):
    `mesh.panels` cuts it into panels with duplicated seam vertices; `mesh.weld` > 0 merges vertices that close,
    before the pins and skinning are derived, so panels welded back give exactly the garment made whole.
    `garment_file` takes the garment the dress stage dressed and settled (`dressed`, pipeline/dress.py), welded
    there already."""
    mesh = settings["mesh"]
    skel = default_skeleton()
    if mesh["generator"] == "garment_file":
        if dressed is None:
            raise ValueError("a garment_file scene is made from its dressed garment (the dress stage's dressed.h5)")
        garment = dressed
    else:
        garment = make_garment(mesh["garment"], skel, mesh["max_edge"], mesh["seed"], mesh["panels"])
        if mesh["weld"] > 0:
            garment = garment.welded(mesh["weld"])
    influences, weights = skinning_weights(skel, garment.vertices, garment.faces)
    pin_ids = garment.attachment if settings["physics"]["pins"] else np.zeros(0, np.int64)
    return SceneRest(name=settings["scene"], generator=mesh["generator"], vertices=garment.vertices,
                     faces=garment.faces, pin_ids=pin_ids, pin_part=garment.attachment_part[:len(pin_ids)],
                     skeleton=skel, skinning_influences=influences, skinning_weights=weights)


def garment_scene(settings: dict, rest: SceneRest, sequence: str) -> Scene:
    """Sequence `sequence` of the garment scene; ValueError for settings it cannot build (too few frames for the
    clips, a BVH file that is missing or cannot be mapped), UnusableWindow for a library window that cannot be
    played (its sequence is dropped, not the run)."""
    drive, skel, fps = settings["drivers"]["mannequin"], rest.skeleton, 1.0 / settings["solver"]["dt"]
    if sequence == SETTLE:      # settle_frames steps at rest: the state every library window starts from
        played = at_rest(drive["settle_frames"] + 1, fps, skel)
        return _posed(settings, rest, sequence, played, (), None, body_state(skel, played.motion))
    if is_window_name(sequence):
        window = find_window(drive["library"], window_key(sequence))
        played = play_window(load_window(window, skel, fps), drive["blend_frames"], drive["library"]["hold_frames"],
                             skel)
        state = body_state(skel, played.motion)
        through = limbs_through_each_other(skel, state.transforms, worn_pairs(rest))
        if through is not None:
            overlap, frame, parts = through
            raise UnusableWindow(f"{window.clip.path}: seconds {window.start:g}-{window.end:g} drive "
                                 f"{' and '.join(parts)} through each other ({overlap * 100:.1f} cm deep, frame "
                                 f"{frame}): the garment would be caught between them")
        return _posed(settings, rest, sequence, played, (), window.describe(), state, settled_start=True)
    role, index = parse_sequence_name(sequence)
    clips = [load_clip(entry, skel, fps) for entry in sequence_clips(settings, sequence)]
    timing = settings["frames"], drive["settle_frames"], drive["blend_frames"]
    if role == TRAIN:
        # Program k draws from its own generator: adding programs leaves the others as they were.
        program = plan_program(clips, *timing, fps, np.random.default_rng([drive["seed"], index]))
        played = play_program(program, *timing, drive["seed"], fps, skel)
    else:
        program = ()
        n_frames = drive["settle_frames"] + clips[0].n_frames if isinstance(clips[0], Motion) else settings["frames"]
        played = play_clips(clips, n_frames, *timing[1:], drive["seed"], fps=fps, skel=skel)
    return _posed(settings, rest, sequence, played, program, None, body_state(skel, played.motion))


# A part is worn under the garment where some vertex's skinning weight on it reaches this.
WORN_WEIGHT = 0.05


def worn_pairs(rest: SceneRest) -> np.ndarray:
    """Part pairs (K, 2) that must not pass through each other under this garment: apart at rest
    (scenes.capsules.self_collision_pairs) and both worn under it, where cloth caught between them would tangle
    (for pants the thighs, not an arm and the chest)."""
    worn = np.unique(rest.skinning_influences[rest.skinning_weights >= WORN_WEIGHT])
    pairs = self_collision_pairs(rest.skeleton)
    return pairs[np.isin(pairs, worn).all(axis=1)]


def _posed(settings: dict, rest: SceneRest, sequence: str, played: ClipSequence, program: tuple,
           library_window: dict | None, state: BodyState, settled_start: bool = False) -> Scene:
    """The sequence of a garment scene whose mannequin plays `played` (the parts' world `state`): its body,
    capsules, pins and poses; `settled_start`: its cloth starts where the settle sequence's runs end."""
    skel = rest.skeleton
    n_frames = played.motion.n_frames
    a, b, radius_a, radius_b = capsules_world(skel, state.transforms)
    velocity_a, velocity_b = capsule_velocities(skel, state.transforms, state.velocities)
    # An attachment vertex is rigidly bound to one part: it moves with that part's rest-to-posed transform.
    transforms = np.tile(np.eye(4), (n_frames, skel.n_parts, 1, 1))
    transforms[..., :3, :] = rest_to_posed(rest_transforms(skel), state.transforms)
    targets = apply_rigid(transforms[:, rest.pin_part], rest.vertices[rest.pin_ids])
    torso = skel.index(TORSO)
    torso_transforms = np.tile(np.eye(4), (n_frames, 1, 1))
    torso_transforms[:, :3, :3] = quat_to_matrix(state.rotation[:, torso])
    torso_transforms[:, :3, 3] = state.translation[:, torso]
    mannequin = Mannequin(
        clips=played, program=program, state=state,
        capsules=PosedCapsules(a=a, b=b, radius_a=radius_a[0], radius_b=radius_b[0], velocity_a=velocity_a,
                               velocity_b=velocity_b),
        pose=pose_vectors(skel, played.motion), torso_transforms=torso_transforms)
    return Scene(rest=rest, sequence=sequence, dt=settings["solver"]["dt"],
                 pins=Pins(ids=rest.pin_ids, part=rest.pin_part, transforms=transforms, targets=targets),
                 mannequin=mannequin, library_window=library_window, settled_start=settled_start)


def load_window(window: LibraryWindow, skel: Skeleton, fps: float) -> Motion:
    """A library window retargeted onto the mannequin at `fps` (its clip at its true frame rate, from its first
    frame of motion); UnusableWindow, naming the file, where it cannot be."""
    clip = window.clip
    if clip.problem:
        raise UnusableWindow(clip.problem)
    try:
        source = read_bvh(clip.path, frame_time=clip.frame_time)
        return retarget(source, skel, fps, window.start, window.end)
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise UnusableWindow(err if str(err).startswith(clip.path) else f"{clip.path}: {err}") from None


def load_clip(entry: str | dict, skel: Skeleton, fps: float) -> str | Motion:
    """A procedural kind as it is, a BVH entry as its retargeted raw Motion at `fps`; a ValueError names the file
    that is missing, unreadable or cannot be mapped onto the mannequin."""
    if isinstance(entry, str):
        return entry
    path = Path(entry["bvh"])
    if not path.is_file():
        raise ValueError(f"{path}: BVH file does not exist (relative paths start in {Path.cwd()})")
    try:
        clip = read_bvh(path)     # its ValueErrors start with the path and line
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read BVH file ({err})") from None
    try:
        return retarget(clip, skel, fps, entry.get("start"), entry.get("end"))
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
