"""The garment scene: a garment on the procedural mannequin playing the configured clips; its attachment
vertices (waist band, shoulders) are pinned to the body part they follow."""
from __future__ import annotations

import numpy as np

from geometry.rigid import apply_rigid
from geometry.rotations import quat_to_matrix
from scenes.capsules import capsule_velocities, capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, play_clips, pose_vectors
from scenes.scene import Mannequin, Pins, PosedCapsules, Scene
from scenes.skeleton import TORSO, default_skeleton
from scenes.skinning import rest_to_posed, skinning_weights


def garment_scene(settings: dict) -> Scene:
    """The garment scene of resolved settings (`mesh.generator: garment`); ValueError for settings it cannot
    build (a mesh too coarse for the garment, too few frames for the clips)."""
    mesh, drive = settings["mesh"], settings["drivers"]["mannequin"]
    skel = default_skeleton()
    garment = make_garment(mesh["garment"], skel, mesh["max_edge"], mesh["seed"])
    clips = play_clips(drive["clips"], settings["frames"], drive["settle_frames"], drive["blend_frames"],
                       drive["seed"], fps=1.0 / settings["solver"]["dt"], skel=skel)
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
    mannequin = Mannequin(
        skeleton=skel, clips=clips, state=state,
        capsules=PosedCapsules(a=a, b=b, radius_a=radius_a[0], radius_b=radius_b[0], velocity_a=velocity_a,
                               velocity_b=velocity_b),
        pose=pose_vectors(skel, clips.motion), torso_transforms=torso_transforms,
        skinning_influences=influences, skinning_weights=weights)
    return Scene(name=settings["scene"], generator=mesh["generator"], dt=settings["solver"]["dt"],
                 rest_vertices=garment.vertices, rest_faces=garment.faces,
                 pins=Pins(ids=pin_ids, part=parts, transforms=transforms, targets=targets), mannequin=mannequin)
