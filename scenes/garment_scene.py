"""The garment scene: a garment on the procedural mannequin, its attachment vertices (waist band, shoulders)
pinned to the body part they follow. Every sequence wears the same garment; a training sequence plays a seeded
motion program over the training clips, a held-out sequence its one test clip (scenes.sequences)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from geometry.rigid import apply_rigid
from geometry.rotations import quat_to_matrix
from scenes.bvh import read_bvh
from scenes.capsules import capsule_velocities, capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.motion import Motion, body_state, play_clips, pose_vectors
from scenes.program import plan_program, play_program
from scenes.scene import Mannequin, Pins, PosedCapsules, Scene, SceneRest
from scenes.retarget import retarget
from scenes.sequences import TRAIN, parse_sequence_name, sequence_clips
from scenes.skeleton import TORSO, Skeleton, default_skeleton
from scenes.skinning import rest_to_posed, skinning_weights


def garment_rest(settings: dict) -> SceneRest:
    """The garment at rest on the mannequin, its attachment pins and skinning (`mesh.generator: garment`);
    ValueError for settings it cannot build (a mesh too coarse for the garment). `mesh.panels` cuts it
    into panels with duplicated seam vertices; `mesh.weld` > 0 merges vertices that close, before the pins and
    skinning are derived, so panels welded back give exactly the garment made whole."""
    mesh = settings["mesh"]
    skel = default_skeleton()
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
    clips, a BVH file that is missing or cannot be mapped)."""
    drive, skel, fps = settings["drivers"]["mannequin"], rest.skeleton, 1.0 / settings["solver"]["dt"]
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
    n_frames = played.motion.n_frames
    state = body_state(skel, played.motion)
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
                 mannequin=mannequin)


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
