"""Pose to cloth (paper Table 2 row 2, section 5.2): the input is the mannequin's pose, 13 scalars per body part
(208 for its 16 parts: position and xyzw rotation relative to the torso, linear and angular velocity in the torso
frame, as scene.h5 `pose` holds them); the predictor is linear blend skinning of the high-res rest garment; the
decoder regresses the displacement from it. No physics at inference: the whole cloth comes from the pose.

The high-res skinning weights are S W_low, the low-res weights (scene.h5 `skinning/`) carried through Loop
subdivision: every row of S sums to 1 and is non-negative, so each high-res vertex blends the parts of the low-res
vertices it is made of, and the rest garment is reproduced exactly in the rest pose.
"""
from __future__ import annotations

import numpy as np

from pipeline.artifacts.dataset import TaskLayout
from pipeline.artifacts.scene import BODY_STATE, POSE, read_body, read_mannequin_frames, read_skinning
from pipeline.core.errors import PipelineError
from pipeline.tasks.decoder import DecoderTask, decoder_frames
from pipeline.tasks.task import DatasetRequest, SequenceRun, in_reference_frames
from scenes.kinematics import rest_transforms
from scenes.skinning import linear_blend_skinning

SKINNING_CHUNK = 64        # frames skinned at once: (chunk, V, 3, 4) float64 blended maps


class PoseTask(DecoderTask):
    name = "pose"
    predictor_label = "linear blend skinning"
    input_label = "linear blend skinning"
    input_description = ("the mannequin's pose, per body part its position (3) and rotation (4, xyzw) relative to "
                         "the torso and its linear and angular velocity (3 + 3) in the torso frame")
    timing_reference = ("Paper Table 4 (RTX 2080 Ti, pose to cloth, RC13 decoder, without the skinning): 10.5 ms "
                        "for dress2 (4,922 vertices), 7.3 ms for tank-male (3,666 vertices).")

    def prepare(self, request: DatasetRequest):
        scene = request.shared_scene
        skinning = read_skinning(scene) if scene is not None else None
        if skinning is None:
            raise PipelineError(f"{scene or 'the sequences'}: task pose: this scene has no mannequin, so no pose "
                                f"input (a grid scene); pose to cloth needs a garment scene")
        skeleton, _ = read_body(scene)
        influences, weights = skinning
        S = request.subdivision.S
        if S.shape[1] != len(weights):
            raise PipelineError(f"{scene}: skinning of {len(weights)} vertices, but the subdivision S is {S.shape}")
        low_weights = np.zeros((len(weights), skeleton.n_parts))
        np.add.at(low_weights, (np.arange(len(weights))[:, None], influences), weights)
        high_weights = np.asarray(S @ low_weights)
        every_part = np.broadcast_to(np.arange(skeleton.n_parts), high_weights.shape)
        rest = request.subdivision.vertices
        rest_pose = rest_transforms(skeleton)
        pose_size = read_mannequin_frames(scene, 0).per_frame[POSE].shape[1]

        def frames(run: SequenceRun):
            if run.mannequin is None:
                raise PipelineError(f"{run.where}: task pose: this sequence has no mannequin (no pose input)")
            state = run.mannequin.per_frame
            rotation, translation = state[f"{BODY_STATE}/rotation"], state[f"{BODY_STATE}/translation"]
            world = np.concatenate([
                linear_blend_skinning(rest, every_part, high_weights, rest_pose,
                                      (rotation[i:i + SKINNING_CHUNK], translation[i:i + SKINNING_CHUNK]))
                for i in range(0, len(rotation), SKINNING_CHUNK)])
            predictor = world if run.transforms is None else in_reference_frames(run.transforms, world)
            return decoder_frames(run, state[POSE], predictor)

        layout = TaskLayout(self.name, pose_size, "pose to cloth (paper Table 2)",
                            f"the mannequin's pose per frame (F, {pose_size}): {self.input_description}",
                            "linear blend skinning of the high-res rest garment (weights S W_low), per frame "
                            "(F, V_high, 3), in the reference frame")
        return layout, frames
