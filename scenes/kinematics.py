"""Forward kinematics of a `Skeleton`: joint angles to joint rotations, part frames in world space, and the exact
linear and angular velocities of every part. Leading axes (e.g. frames) broadcast.

Part p's world transform is R_p = R_parent frame_rotations[p] joint_rotation[p] and
t_p = t_parent + R_parent joint_offsets[p]; the root's translation is the motion's root position.
"""
from __future__ import annotations

import numpy as np

from geometry.rotations import UNIT_X, UNIT_Y, UNIT_Z, quat_from_axis_angle, quat_multiply, quat_rotate
from scenes.skeleton import Skeleton


def joint_quaternions(angles: np.ndarray) -> np.ndarray:
    """Joint rotations (..., 4) from joint angles (..., 3): R = Rz(a_z) Rx(a_x) Ry(a_y)."""
    angles = np.asarray(angles, dtype=np.float64)
    return quat_multiply(quat_from_axis_angle(UNIT_Z, angles[..., 2]),
                         quat_multiply(quat_from_axis_angle(UNIT_X, angles[..., 0]),
                                       quat_from_axis_angle(UNIT_Y, angles[..., 1])))


def joint_angular_velocity(angles: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Angular velocity (..., 3) of R = Rz Rx Ry for angle rates (..., 3), in the frame the joint rotates in."""
    angles = np.asarray(angles, dtype=np.float64)
    rates = np.asarray(rates, dtype=np.float64)
    qz = quat_from_axis_angle(UNIT_Z, angles[..., 2])
    qzx = quat_multiply(qz, quat_from_axis_angle(UNIT_X, angles[..., 0]))
    return (rates[..., 2:3] * UNIT_Z + rates[..., 0:1] * quat_rotate(qz, UNIT_X)
            + rates[..., 1:2] * quat_rotate(qzx, UNIT_Y))


def forward_kinematics(skel: Skeleton, root_position: np.ndarray,
                       joint_rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (..., P, 4) and translations (..., P, 3) of every part frame.

    root_position (..., 3) is the world position of the pelvis origin; joint_rotations (..., P, 4) the local
    joint rotations (the root's is its world orientation). Leading axes (e.g. frames) broadcast.
    """
    joint_rotations = np.asarray(joint_rotations, dtype=np.float64)
    root_position = np.asarray(root_position, dtype=np.float64)
    if joint_rotations.shape[-2:] != (skel.n_parts, 4):
        raise ValueError(f"joint_rotations must have shape (..., {skel.n_parts}, 4), got {joint_rotations.shape}")
    batch = np.broadcast_shapes(joint_rotations.shape[:-2], root_position.shape[:-1])
    rotation = np.empty(batch + (skel.n_parts, 4))
    translation = np.empty(batch + (skel.n_parts, 3))
    for p, parent in enumerate(skel.parents):
        local = quat_multiply(skel.frame_rotations[p], joint_rotations[..., p, :])
        if parent < 0:
            rotation[..., p, :] = local
            translation[..., p, :] = root_position
        else:
            rotation[..., p, :] = quat_multiply(rotation[..., parent, :], local)
            translation[..., p, :] = translation[..., parent, :] + quat_rotate(rotation[..., parent, :],
                                                                               skel.joint_offsets[p])
    rotation /= np.linalg.norm(rotation, axis=-1, keepdims=True)
    return rotation, translation


def rest_transforms(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (P, 4) and translations (P, 3) of the rest pose."""
    identity = np.tile([0.0, 0.0, 0.0, 1.0], (skel.n_parts, 1))
    return forward_kinematics(skel, skel.joint_offsets[0], identity)


def part_velocities(skel: Skeleton, part_rotation: np.ndarray, joint_omega: np.ndarray,
                    root_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World linear velocity of each part origin and world angular velocity of each part, (..., P, 3) each.

    part_rotation (..., P, 4) comes from `forward_kinematics`; joint_omega (..., P, 3) is each joint's angular
    velocity in the frame it rotates in (see `joint_angular_velocity`); root_velocity (..., 3) that of the root.
    """
    part_rotation = np.asarray(part_rotation, dtype=np.float64)
    joint_omega = np.asarray(joint_omega, dtype=np.float64)
    shape = part_rotation.shape[:-1] + (3,)
    linear, angular = np.empty(shape), np.empty(shape)
    for p, parent in enumerate(skel.parents):
        if parent < 0:
            angular[..., p, :] = quat_rotate(skel.frame_rotations[p], joint_omega[..., p, :])
            linear[..., p, :] = root_velocity
        else:
            base = quat_multiply(part_rotation[..., parent, :], skel.frame_rotations[p])
            angular[..., p, :] = angular[..., parent, :] + quat_rotate(base, joint_omega[..., p, :])
            lever = quat_rotate(part_rotation[..., parent, :], skel.joint_offsets[p])
            linear[..., p, :] = linear[..., parent, :] + np.cross(angular[..., parent, :], lever)
    return linear, angular
