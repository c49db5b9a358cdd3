"""Procedural, seeded mannequin motions and the per-frame pose vector of the Pose to Cloth problem.

A motion holds still in the rest pose for `settle_frames` (so the cloth can settle, as the paper pauses 100
frames), then fades in over `blend_frames` with a quintic smoothstep weight w(t): angles = w * raw(t). The raw
motions are smooth curves with analytic time derivatives (sums of sinusoids, or monotone cubic Hermite (PCHIP)
splines through keyframes), so the result is C¹ in time and the angular and linear velocities are exact rather
than differenced. Because every joint-limit box contains the rest pose, w * raw stays within the limits whenever
raw does; a smooth soft clamp guarantees the latter for the sinusoidal motions. The raw motions say nothing about
the root height: it is set so that the lower foot stays on the ground (a smooth minimum over the foot capsules,
lightly smoothed in time so that the weight passes from foot to foot without a jolt).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d

from geometry.rotations import quat_canonical, quat_conjugate, quat_multiply, quat_rotate
from scenes.capsules import capsule_pair_clearance, self_collision_pairs
from scenes.kinematics import (forward_kinematics, joint_angular_velocity, joint_quaternions, part_velocities,
                               rest_transforms)
from scenes.skeleton import TORSO, Skeleton, default_skeleton, mirror_name

MOTION_KINDS = ("rest", "walk", "dance", "karate", "random", "exercise")
SOFT_LIMIT_MARGIN = 0.05  # fraction of a joint's range over which the soft clamp bends values into the limit
GROUND_SOFTNESS = 0.005   # length (for a 1.7 body) over which the lower foot smoothly takes the weight
GROUND_SMOOTHING = 0.05   # seconds (Gaussian sigma): the body's give when the weight passes to the other foot


@dataclass(frozen=True, eq=False)
class Motion:
    """Per-frame root position/velocity and joint angles/rates of a mannequin animation sampled at `fps`."""
    kind: str
    fps: float
    seed: int
    settle_frames: int
    blend_frames: int
    root_position: np.ndarray      # (F, 3) world position of the pelvis origin
    root_velocity: np.ndarray      # (F, 3) units/s
    joint_angles: np.ndarray       # (F, P, 3) radians, see scenes.skeleton
    joint_angle_rates: np.ndarray  # (F, P, 3) radians/s

    @property
    def n_frames(self) -> int:
        return len(self.root_position)

    @property
    def joint_rotations(self) -> np.ndarray:
        """(F, P, 4) joint quaternions (x, y, z, w)."""
        return joint_quaternions(self.joint_angles)


class BodyState(NamedTuple):
    """World state of every body part per frame: rotation (F, P, 4), translation (F, P, 3) of the part origin,
    linear velocity (F, P, 3) of the part origin and angular velocity (F, P, 3)."""
    rotation: np.ndarray
    translation: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray

    @property
    def transforms(self) -> tuple[np.ndarray, np.ndarray]:
        return self.rotation, self.translation

    @property
    def velocities(self) -> tuple[np.ndarray, np.ndarray]:
        return self.linear_velocity, self.angular_velocity


class ClipCurves(NamedTuple):
    """A raw motion sampled at motion times tau (T,): horizontal root offset from the rest root and joint angles,
    with their time derivatives, plus a constant travel velocity that the fade-in ramps up. The root height is
    not part of it: make_motion derives it by keeping the feet on the ground."""
    offset: np.ndarray       # (T, 3), y = 0
    offset_rate: np.ndarray  # (T, 3)
    angles: np.ndarray       # (T, P, 3)
    rates: np.ndarray        # (T, P, 3)
    travel: np.ndarray       # (3,)


def make_motion(kind: str, n_frames: int, fps: float = 60.0, seed: int = 0, settle_frames: int = 100,
                blend_frames: int = 60, skel: Skeleton | None = None) -> Motion:
    """A seeded motion of `kind` (one of MOTION_KINDS) for the skeleton (default: `default_skeleton()`)."""
    if n_frames < 1 or fps <= 0 or settle_frames < 0 or blend_frames < 1:
        raise ValueError(f"need n_frames >= 1, fps > 0, settle_frames >= 0, blend_frames >= 1; got {n_frames}, "
                         f"{fps}, {settle_frames}, {blend_frames}")
    skel = skel or default_skeleton()
    # Evaluate past the end so that smoothing the ground lift sees the true signal on both sides of every frame.
    pad = int(np.ceil(4 * GROUND_SMOOTHING * fps))
    tau = np.maximum(np.arange(n_frames + pad) / fps - settle_frames / fps, 0.0)
    curves = clip_curves(kind, skel, seed, tau)
    w, dw, w_integral = fade_in(tau, blend_frames / fps)
    angles = w[:, None, None] * curves.angles
    rates = dw[:, None, None] * curves.angles + w[:, None, None] * curves.rates
    root = skel.joint_offsets[0] + w[:, None] * curves.offset + w_integral[:, None] * curves.travel
    root_velocity = dw[:, None] * curves.offset + w[:, None] * (curves.offset_rate + curves.travel)
    # The fade-in weight keeps the smoothed lift from reaching back into the still settle frames.
    lift, lift_rate = ground_lift(skel, root, root_velocity, angles, rates, fps)
    root[:, 1] += w * lift
    root_velocity[:, 1] += dw * lift + w * lift_rate
    keep = slice(0, n_frames)
    return Motion(kind=kind, fps=float(fps), seed=int(seed), settle_frames=int(settle_frames),
                  blend_frames=int(blend_frames), root_position=root[keep], root_velocity=root_velocity[keep],
                  joint_angles=angles[keep], joint_angle_rates=rates[keep])


def body_state(skel: Skeleton, motion: Motion) -> BodyState:
    """World transforms and exact velocities of every part for every frame of a motion."""
    rotation, translation = forward_kinematics(skel, motion.root_position, motion.joint_rotations)
    joint_omega = joint_angular_velocity(motion.joint_angles, motion.joint_angle_rates)
    linear, angular = part_velocities(skel, rotation, joint_omega, motion.root_velocity)
    return BodyState(rotation, translation, linear, angular)


def pose_vectors(skel: Skeleton, motion: Motion) -> np.ndarray:
    """The Pose to Cloth input, (F, 13 P): for each part in skeleton order, its origin position (3) and rotation
    (4, x y z w with w >= 0) relative to the torso (pelvis) frame, then its world linear velocity (3) and world
    angular velocity (3) expressed in the torso frame. The torso's own entry thus carries the body's overall
    motion (its position is 0 and rotation the identity), which is what makes cloth lag behind."""
    state = body_state(skel, motion)
    torso = skel.index(TORSO)
    inverse = quat_conjugate(state.rotation[:, torso:torso + 1])
    position = quat_rotate(inverse, state.translation - state.translation[:, torso:torso + 1])
    rotation = quat_canonical(quat_multiply(inverse, state.rotation))
    linear = quat_rotate(inverse, state.linear_velocity)
    angular = quat_rotate(inverse, state.angular_velocity)
    return np.concatenate([position, rotation, linear, angular], axis=-1).reshape(motion.n_frames, -1)


def soft_limit(angles: np.ndarray, rates: np.ndarray, lower: np.ndarray,
               upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map angles into [lower, upper] smoothly (C²): identity inside the limits shrunk by a margin of
    SOFT_LIMIT_MARGIN of the range, a tanh approach to the limit beyond. Rates follow by the chain rule.
    Degrees of freedom with an empty range are held at 0."""
    margin = SOFT_LIMIT_MARGIN * (upper - lower)
    fixed = margin <= 0.0
    m = np.where(fixed, 1.0, margin)
    hi, lo = upper - m, lower + m
    over = np.tanh((angles - hi) / m)
    under = np.tanh((lo - angles) / m)
    value = np.where(angles > hi, hi + m * over, np.where(angles < lo, lo - m * under, angles))
    slope = np.where(angles > hi, 1.0 - over ** 2, np.where(angles < lo, 1.0 - under ** 2, 1.0))
    return np.where(fixed, 0.0, value), np.where(fixed, 0.0, slope * rates)


def fade_in(tau: np.ndarray, duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic smoothstep weight w, its time derivative and its time integral, for motion time tau."""
    u = np.clip(tau / duration, 0.0, 1.0)
    w = u ** 3 * (6 * u * u - 15 * u + 10)
    dw = 30 * u * u * (u - 1) ** 2 / duration
    integral = duration * (u ** 6 - 3 * u ** 5 + 2.5 * u ** 4) + np.maximum(tau - duration, 0.0)
    return w, dw, integral


def clip_curves(kind: str, skel: Skeleton, seed: int, tau: np.ndarray, speed: float = 1.0,
                amplitude: float = 1.0, phase: float = 0.0) -> ClipCurves:
    """The raw motion of `kind` at clip times tau (T,) >= 0, played `speed` times as fast from `phase` seconds into
    its curves, with joint angles and the root's offset and travel scaled by `amplitude`. Angles scaled up are
    softly clamped back into the joint limits; scaled down they stay inside, since every limit box holds the rest
    pose. A walk's travel scales with its stride only approximately (its feet may slip a little)."""
    if kind not in MOTION_KINDS:
        raise ValueError(f"unknown motion kind '{kind}'; choose one of {', '.join(MOTION_KINDS)}")
    raw = _GENERATORS[kind](skel, np.random.default_rng(seed), speed * np.asarray(tau) + phase)
    angles, rates = amplitude * raw.angles, amplitude * speed * raw.rates
    if amplitude > 1.0:
        angles, rates = soft_limit(angles, rates, skel.joint_lower, skel.joint_upper)
    return ClipCurves(amplitude * raw.offset, amplitude * speed * raw.offset_rate, angles, rates,
                      amplitude * speed * raw.travel)


def ground_lift(skel: Skeleton, root: np.ndarray, root_velocity: np.ndarray, angles: np.ndarray,
                rates: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertical root shift (F,) and its rate that keep the lowest foot on the ground (see _foot_lift), smoothed
    over GROUND_SMOOTHING seconds: the body's give when the weight passes from foot to foot. Smoothing a function
    and its derivative with the same kernel keeps one the derivative of the other. Frames are `1 / fps` apart."""
    sigma = GROUND_SMOOTHING * fps
    lift, lift_rate = _foot_lift(skel, root, root_velocity, angles, rates)
    return gaussian_filter1d(lift, sigma, mode="nearest"), gaussian_filter1d(lift_rate, sigma, mode="nearest")


def _foot_lift(skel: Skeleton, root: np.ndarray, root_velocity: np.ndarray, angles: np.ndarray,
               rates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertical root shift (F,) and its rate that keep the lowest foot point where it is in the rest pose.

    The lowest point is a smooth minimum (soft-min over the bottoms of the four foot-capsule spheres), so the
    shift is as smooth as the pose and its rate is exact: minus the soft-min-weighted vertical velocities of the
    sphere bottoms. The rest pose's soft minimum is subtracted so that the rest pose is not shifted.
    """
    rotation, translation = forward_kinematics(skel, root, joint_quaternions(angles))
    linear, angular = part_velocities(skel, rotation, joint_angular_velocity(angles, rates), root_velocity)
    bottom, bottom_rate = _foot_bottoms(skel, rotation, translation, linear, angular)
    rest_rotation, rest_translation = rest_transforms(skel)
    rest_bottom, _ = _foot_bottoms(skel, rest_rotation, rest_translation, np.zeros_like(rest_translation),
                                   np.zeros_like(rest_translation))
    softness = GROUND_SOFTNESS * skel.height / 1.7
    lowest, rest_lowest = bottom.min(-1, keepdims=True), rest_bottom.min()
    weight = np.exp(-(bottom - lowest) / softness)
    soft_lowest = lowest[:, 0] - softness * np.log(weight.sum(-1))
    soft_rest = rest_lowest - softness * np.log(np.exp(-(rest_bottom - rest_lowest) / softness).sum())
    weight /= weight.sum(-1, keepdims=True)
    return soft_rest - soft_lowest, -(weight * bottom_rate).sum(-1)


def _foot_bottoms(skel: Skeleton, rotation: np.ndarray, translation: np.ndarray, linear: np.ndarray,
                  angular: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heights (..., 4) of the lowest points of the two spheres of each foot capsule, and their rates."""
    feet = [skel.index("foot_l"), skel.index("foot_r")] * 2
    centers = np.concatenate([skel.capsule_a[feet[:2]], skel.capsule_b[feet[:2]]])
    radii = np.concatenate([skel.radius_a[feet[:2]], skel.radius_b[feet[:2]]])
    arm = quat_rotate(rotation[..., feet, :], centers)
    height = (translation[..., feet, :] + arm)[..., 1] - radii
    rate = (linear[..., feet, :] + np.cross(angular[..., feet, :], arm))[..., 1]
    return height, rate


# ---------------------------------------------------------------------------------------------------------------
# Sinusoidal motions


class _Waves:
    """Accumulates joint-angle curves c + sum a sin(k phase + p) with exact derivatives (phase = omega tau)."""

    def __init__(self, skel: Skeleton, tau: np.ndarray, omega: float):
        self.skel, self.tau, self.omega = skel, tau, omega
        self.angles = np.zeros((len(tau), skel.n_parts, 3))
        self.rates = np.zeros_like(self.angles)

    def add(self, part: str, axis: int, const: float = 0.0, terms=(), side_phase: float = 0.0,
            both_sides: bool = True) -> None:
        """Add a curve to a part's axis, in anatomical terms: for a right part, y and z are mirrored (negated)
        so that equal values mean mirror-image poses. With both_sides, a left or right part's twin gets the same
        curve shifted by side_phase cycles of the base frequency."""
        targets = [part]
        if both_sides and mirror_name(part) != part:
            targets.append(mirror_name(part))
        for name, shift in zip(targets, (0.0, side_phase)):
            sign = -1.0 if name.endswith("_r") and axis else 1.0
            p = self.skel.index(name)
            self.angles[:, p, axis] += sign * const
            for amplitude, harmonic, phase in terms:
                arg = harmonic * (self.omega * self.tau + 2 * np.pi * shift) + phase
                self.angles[:, p, axis] += sign * amplitude * np.sin(arg)
                self.rates[:, p, axis] += sign * amplitude * harmonic * self.omega * np.cos(arg)

    def add_flexion_bump(self, part: str, height: float, center: float, concentration: float,
                         side_phase: float) -> None:
        """Add a periodic bump h exp(k (cos(phase - center) - 1)) (a von Mises profile: one smooth peak per
        cycle, nearly flat elsewhere) to a part's flexion (x) angle and, shifted by side_phase cycles, to its
        twin's."""
        for name, shift in zip((part, mirror_name(part)), (0.0, side_phase)):
            arg = self.omega * self.tau + 2 * np.pi * shift - center
            value = height * np.exp(concentration * (np.cos(arg) - 1.0))
            p = self.skel.index(name)
            self.angles[:, p, 0] += value
            self.rates[:, p, 0] -= value * concentration * np.sin(arg) * self.omega

    def limited(self) -> tuple[np.ndarray, np.ndarray]:
        """The accumulated angles and rates, softly clamped into the joint limits."""
        return soft_limit(self.angles, self.rates, self.skel.joint_lower, self.skel.joint_upper)


def _leg_length(skel: Skeleton) -> float:
    """Hip-to-ankle length of the left leg."""
    return float(np.linalg.norm(skel.joint_offsets[skel.index("shin_l")])
                 + np.linalg.norm(skel.joint_offsets[skel.index("foot_l")]))


def _rest(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    zeros = np.zeros((len(tau), skel.n_parts, 3))
    return ClipCurves(np.zeros((len(tau), 3)), np.zeros((len(tau), 3)), zeros, zeros.copy(), np.zeros(3))


def _walk(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    """A walking gait along +z: hips swing from 26° forward to 17° back, knees flex in swing, arms swing
    against the legs, pelvis and shoulders counter-rotate, the pelvis shifts over the stance leg. Seeds vary
    cadence, amplitude and the leading foot."""
    scale = skel.height / 1.7
    period = 1.1 * np.sqrt(scale) * rng.uniform(0.92, 1.08)
    amp = rng.uniform(0.88, 1.12)
    lead = 0.5 * rng.integers(0, 2)
    omega = 2 * np.pi / period
    waves = _Waves(skel, tau + lead * period, omega)
    half = 0.5  # the right side runs half a cycle behind the left
    hip = 0.38 * amp
    waves.add("thigh_l", 0, -0.08, [(-hip, 1, 0.0)], half)
    # Knee: flexes once in early swing and is nearly straight and still at heel strike (phase pi/2), so the
    # landing foot comes down gently and the ground contact passes smoothly from foot to foot.
    waves.add_flexion_bump("shin_l", 0.05, np.pi, 1.0, half)
    waves.add_flexion_bump("shin_l", 0.95 * amp, 0.1, 4.0, half)
    waves.add("foot_l", 0, 0.0, [(-0.2 * amp, 1, 0.2)], half)
    waves.add("upper_arm_l", 0, 0.0, [(0.3 * amp, 1, 0.0)], half)
    waves.add("upper_arm_l", 2, -0.45, (), half)
    waves.add("lower_arm_l", 0, -0.35, [(0.15 * amp, 1, 0.0)], half)
    waves.add("pelvis", 1, 0.0, [(-0.1 * amp, 1, 0.0)])
    waves.add("pelvis", 2, 0.0, [(0.04 * amp, 1, 0.0)])
    waves.add("spine", 1, 0.0, [(0.06 * amp, 1, 0.0)])
    waves.add("chest", 1, 0.0, [(0.08 * amp, 1, 0.0)])
    waves.add("head", 1, 0.0, [(-0.04 * amp, 1, 0.0)])
    phase = omega * (tau + lead * period)
    sway = 0.02 * scale * amp  # the pelvis shifts over the stance leg
    offset = np.stack([-sway * np.cos(phase), np.zeros_like(tau), np.zeros_like(tau)], axis=1)
    offset_rate = np.stack([sway * omega * np.sin(phase), np.zeros_like(tau), np.zeros_like(tau)], axis=1)
    # Each step the stance leg sweeps from +hip to -hip: two steps of 2 L sin(hip) per cycle.
    speed = 4 * _leg_length(skel) * np.sin(hip) / period
    return ClipCurves(offset, offset_rate, *waves.limited(), np.array([0.0, 0.0, speed]))


def _dance(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    """Dance-like: knees bounce on the beat (thigh -k/2, knee k, ankle -k/2 keep the feet flat), hips sway
    every two beats, the body turns slowly, arms raise, swing and bend with seeded phases, the head nods."""
    scale = skel.height / 1.7
    beat = rng.uniform(1.6, 2.1)  # beats per second
    omega = 2 * np.pi * beat
    ph = rng.uniform(0, 2 * np.pi, size=12)
    amp = rng.uniform(0.8, 1.2, size=6)
    waves = _Waves(skel, tau, omega)
    bounce = 0.22 * amp[0]
    waves.add("shin_l", 0, 0.3, [(bounce, 1, ph[0])])
    waves.add("thigh_l", 0, -0.15, [(-0.5 * bounce, 1, ph[0])])
    waves.add("foot_l", 0, -0.15, [(-0.5 * bounce, 1, ph[0])])
    waves.add("pelvis", 2, 0.0, [(-0.06 * amp[1], 0.5, ph[1])])
    waves.add("spine", 2, 0.0, [(0.05 * amp[1], 0.5, ph[1])])
    waves.add("pelvis", 1, 0.0, [(0.5 * amp[2], 0.125, ph[2])])
    waves.add("chest", 1, 0.0, [(0.2 * amp[2], 0.5, ph[3])])
    for side, k in (("l", 4), ("r", 8)):  # each arm has its own phases
        waves.add(f"upper_arm_{side}", 2, 0.35, [(0.6 * amp[3], 0.5, ph[k])], both_sides=False)
        waves.add(f"upper_arm_{side}", 0, -0.35, [(0.5 * amp[4], 0.25, ph[k + 1])], both_sides=False)
        waves.add(f"lower_arm_{side}", 0, -0.9, [(0.5 * amp[5], 1, ph[k + 2])], both_sides=False)
        waves.add(f"hand_{side}", 0, 0.0, [(0.3, 1, ph[k + 3])], both_sides=False)
    waves.add("head", 0, 0.0, [(0.12, 1, ph[2] + 1.0)])
    waves.add("head", 1, 0.0, [(0.25, 0.25, ph[3] + 2.0)])
    sway = 0.035 * scale * amp[1]
    arg = 0.5 * omega * tau + ph[1]
    zero = np.zeros_like(tau)
    offset = np.stack([sway * np.sin(arg), zero, zero], axis=1)
    offset_rate = np.stack([0.5 * omega * sway * np.cos(arg), zero, zero], axis=1)
    return ClipCurves(offset, offset_rate, *waves.limited(), np.zeros(3))


# ---------------------------------------------------------------------------------------------------------------
# Keyframed motions: monotone cubic Hermite (PCHIP) splines never overshoot their keyframes, so keyframes within
# the joint limits give curves within them.


def _pose(skel: Skeleton, degrees: dict[str, tuple[float, float, float]]) -> np.ndarray:
    """Joint angles (P, 3) from anatomical degrees per part (right parts' y and z mirrored)."""
    angles = np.zeros((skel.n_parts, 3))
    for name, values in degrees.items():
        sign = np.array([1.0, -1.0, -1.0]) if name.endswith("_r") else np.ones(3)
        angles[skel.index(name)] = sign * np.radians(values)
    return angles


def _mirror_pose(degrees: dict[str, tuple[float, float, float]]) -> dict[str, tuple[float, float, float]]:
    """The mirror-image pose in anatomical terms: twins swap, midline y and z turn the other way."""
    return {mirror_name(name): (x, y, z) if mirror_name(name) != name else (x, -y, -z)
            for name, (x, y, z) in degrees.items()}


def _keyframed(skel: Skeleton, times: np.ndarray, poses: np.ndarray, tau: np.ndarray) -> ClipCurves:
    """PCHIP through keyframe poses (K, P, 3) at `times`, standing in place (the root only rises and falls with
    the ground contact)."""
    spline = PchipInterpolator(times, poses, axis=0)
    zero = np.zeros((len(tau), 3))
    return ClipCurves(zero, zero.copy(), spline(tau), spline.derivative()(tau), np.zeros(3))


Moves = dict[str, list[tuple[dict[str, tuple[float, float, float]], float]]]


def _routine(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray, moves: Moves,
             home: dict[str, tuple[float, float, float]], lead: float, pause: float,
             tempo: tuple[float, float]) -> ClipCurves:
    """A seeded sequence of `moves` (each a list of (pose, seconds to reach it)), every one from and back to the
    `home` pose, at a seeded tempo drawn from `tempo` per move: `lead` s at home first, `pause` s after each."""
    names = sorted(moves)
    times, poses = [0.0, lead], [home, home]
    while times[-1] <= tau[-1]:
        speed = rng.uniform(*tempo)
        for pose, dt in moves[names[rng.integers(len(names))]] + [(home, pause)]:
            times.append(times[-1] + dt * speed)
            poses.append(pose)
    return _keyframed(skel, np.array(times), np.stack([_pose(skel, p) for p in poses]), tau)


_GUARD = {"thigh_l": (-30, 0, 8), "shin_l": (40, 0, 0), "foot_l": (-10, 0, 0),
          "thigh_r": (-30, 0, 8), "shin_r": (40, 0, 0), "foot_r": (-10, 0, 0), "spine": (8, 0, 0),
          "upper_arm_l": (-45, 0, -25), "lower_arm_l": (-110, 0, 0),
          "upper_arm_r": (-45, 0, -25), "lower_arm_r": (-110, 0, 0)}
_CHAMBER_ARM_L = {"upper_arm_l": (20, 0, -25), "lower_arm_l": (-120, 0, 0)}
_CHAMBER_ARM_R = _mirror_pose(_CHAMBER_ARM_L)
_PUNCH_R = {**_GUARD, **_CHAMBER_ARM_L, "upper_arm_r": (-85, 0, -25), "lower_arm_r": (-5, 0, 0),
            "chest": (0, 20, 0), "spine": (5, 10, 0)}
_BLOCK_R = {**_GUARD, **_CHAMBER_ARM_L, "upper_arm_r": (-110, 0, 10), "lower_arm_r": (-80, 0, 0),
            "chest": (0, 10, 0)}
_STAND_L = {"thigh_l": (-15, 0, 5), "shin_l": (25, 0, 0), "foot_l": (-10, 0, 0)}
_KICK_CHAMBER_R = {**_GUARD, **_STAND_L, "thigh_r": (-95, 0, 0), "shin_r": (110, 0, 0), "foot_r": (20, 0, 0)}
_KICK_R = {**_KICK_CHAMBER_R, "thigh_r": (-85, 0, 0), "shin_r": (10, 0, 0), "foot_r": (35, 0, 0),
           "spine": (-8, 0, 0)}
# Each technique: (pose, seconds to reach it from the previous keyframe), ending back in guard.
_TECHNIQUES = {
    "punch_r": [({**_GUARD, **_CHAMBER_ARM_R}, 0.25), (_PUNCH_R, 0.15), (_PUNCH_R, 0.1), (_GUARD, 0.3)],
    "block_r": [({**_GUARD, **_CHAMBER_ARM_R}, 0.25), (_BLOCK_R, 0.2), (_BLOCK_R, 0.15), (_GUARD, 0.3)],
    "kick_r": [(_KICK_CHAMBER_R, 0.3), (_KICK_R, 0.18), (_KICK_R, 0.08), (_KICK_CHAMBER_R, 0.2), (_GUARD, 0.3)],
}
_TECHNIQUES.update({name[:-1] + "l": [(_mirror_pose(pose), dt) for pose, dt in steps]
                    for name, steps in list(_TECHNIQUES.items())})


def _karate(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    """Karate-like: from a guard stance, a seeded sequence of punches, rising blocks and front kicks with either
    side, each chambered, struck, held briefly and withdrawn to guard; seeds vary order and tempo."""
    return _routine(skel, rng, tau, _TECHNIQUES, _GUARD, lead=0.4, pause=0.25, tempo=(0.85, 1.15))


# Exercises in place: what a training program needs that dance, karate and random poses lack (deep, slow and
# held flexion of both legs, one leg lifted high or out to the side, the trunk bent and twisted over the hips).
_STANCE = {"thigh_l": (-5, 0, 4), "shin_l": (8, 0, 0), "foot_l": (-3, 0, 0),
           "thigh_r": (-5, 0, 4), "shin_r": (8, 0, 0), "foot_r": (-3, 0, 0)}
_SQUAT = {"thigh_l": (-50, 0, 12), "shin_l": (72, 0, 0), "foot_l": (-22, 0, 0),
          "thigh_r": (-50, 0, 12), "shin_r": (72, 0, 0), "foot_r": (-22, 0, 0), "spine": (15, 0, 0),
          "upper_arm_l": (-80, 0, 0), "upper_arm_r": (-80, 0, 0)}
_KNEE_UP_L = {**_STANCE, "thigh_l": (-80, 0, 0), "shin_l": (90, 0, 0), "foot_l": (10, 0, 0),
              "upper_arm_l": (20, 0, 0), "upper_arm_r": (-30, 0, 0), "lower_arm_l": (-60, 0, 0),
              "lower_arm_r": (-60, 0, 0)}
_LEG_OUT_L = {**_STANCE, "thigh_l": (0, 0, 30), "shin_l": (5, 0, 0), "pelvis": (0, 0, -6),
              "upper_arm_l": (0, 0, 40), "upper_arm_r": (0, 0, 40)}
_TOE_REACH = {"spine": (35, 0, 0), "chest": (20, 0, 0), "head": (20, 0, 0), "thigh_l": (-25, 0, 4),
              "thigh_r": (-25, 0, 4), "shin_l": (8, 0, 0), "shin_r": (8, 0, 0), "foot_l": (-3, 0, 0),
              "foot_r": (-3, 0, 0), "upper_arm_l": (-70, 0, 0), "upper_arm_r": (-70, 0, 0)}
_TWIST_L = {**_STANCE, "spine": (0, 25, 0), "chest": (0, 20, 0), "head": (0, 15, 0),
            "upper_arm_l": (0, 0, 40), "upper_arm_r": (0, 0, 40), "lower_arm_l": (-20, 0, 0),
            "lower_arm_r": (-20, 0, 0)}
# Each exercise: (pose, seconds to reach it from the previous keyframe), ending back in the stance.
_EXERCISES = {
    "squat": [(_SQUAT, 0.9), (_SQUAT, 0.3), (_STANCE, 0.8)],
    "knee_up_l": [(_KNEE_UP_L, 0.5), (_KNEE_UP_L, 0.25), (_STANCE, 0.45)],
    "leg_out_l": [(_LEG_OUT_L, 0.5), (_LEG_OUT_L, 0.2), (_STANCE, 0.45)],
    "toe_reach": [(_TOE_REACH, 1.0), (_TOE_REACH, 0.3), (_STANCE, 0.9)],
    "twist_l": [(_TWIST_L, 0.6), (_TWIST_L, 0.15), (_STANCE, 0.5)],
}
_EXERCISES.update({name[:-1] + "r": [(_mirror_pose(pose), dt) for pose, dt in steps]
                   for name, steps in list(_EXERCISES.items()) if name.endswith("_l")})


def _exercise(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    """Exercises in place: a seeded sequence of squats, knee raises and side leg raises with either leg, forward
    toe reaches and trunk twists either way, each from and back to a relaxed stance, at a seeded tempo."""
    return _routine(skel, rng, tau, _EXERCISES, _STANCE, lead=0.3, pause=0.2, tempo=(0.8, 1.25))


# Fraction of each joint's range that random poses draw from: wide for arms and head, narrow for the legs so
# the mannequin stays standing.
_RANDOM_REACH = {"pelvis": 0.3, "spine": 0.5, "chest": 0.5, "head": 0.6, "upper_arm": 0.7, "lower_arm": 0.7,
                 "hand": 0.5, "thigh": 0.35, "shin": 0.35, "foot": 0.4}


def _random(skel: Skeleton, rng: np.random.Generator, tau: np.ndarray) -> ClipCurves:
    """Random poses within a comfortable part of the joint limits, one every 0.5-1.1 s, joined by PCHIP.
    A candidate pose is rejected if any two capsules that are apart at rest come closer than 1% of the height,
    in the pose itself or on the way to it from the previous keyframe (checked at the quarter points)."""
    reach = np.array([_RANDOM_REACH[name.removesuffix("_l").removesuffix("_r")] for name in skel.names])
    lower, upper = reach[:, None] * skel.joint_lower, reach[:, None] * skel.joint_upper
    pairs = self_collision_pairs(skel)
    min_gap = 0.01 * skel.height
    times, poses = [0.0], [np.zeros((skel.n_parts, 3))]
    while times[-1] <= tau[-1]:
        poses.append(_draw_clear_pose(skel, rng, lower, upper, poses[-1], pairs, min_gap))
        times.append(times[-1] + rng.uniform(0.5, 1.1))
    return _keyframed(skel, np.array(times), np.stack(poses), tau)


def _draw_clear_pose(skel: Skeleton, rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray,
                     previous: np.ndarray, pairs: np.ndarray, min_gap: float, batch: int = 32,
                     attempts: int = 20) -> np.ndarray:
    """First of batches of uniform candidates whose path from `previous` stays clear; `previous` if none is."""
    fractions = np.array([0.25, 0.5, 0.75, 1.0])
    for _ in range(attempts):
        candidates = rng.uniform(lower, upper, size=(batch,) + lower.shape)
        path = previous + fractions[:, None, None, None] * (candidates - previous)       # (4, batch, P, 3)
        transforms = forward_kinematics(skel, skel.joint_offsets[0], joint_quaternions(path))
        clear = (capsule_pair_clearance(skel, transforms, pairs) > min_gap).all(axis=(0, 2))
        if clear.any():
            return candidates[np.argmax(clear)]
    return previous


_GENERATORS: dict[str, Callable[[Skeleton, np.random.Generator, np.ndarray], ClipCurves]] = {
    "rest": _rest, "walk": _walk, "dance": _dance, "karate": _karate, "random": _random, "exercise": _exercise}


@dataclass(frozen=True, eq=False)
class ClipSequence:
    """Motions played one after another: the concatenated motion and, per frame, which clip it belongs to
    (index into `names`; index 0, "settle", marks the rest frames before the first clip)."""
    motion: Motion
    clip: np.ndarray   # (F,) int64
    names: tuple[str, ...]


def play_clips(clips: list[str | Motion], n_frames: int, settle_frames: int, blend_frames: int, seed: int,
               fps: float = 60.0, skel: Skeleton | None = None) -> ClipSequence:
    """`settle_frames` at rest, then each clip in turn. A clip is a procedural kind (make_motion, on an equal
    share of the frames the others leave) or a precomputed raw Motion at `fps` (scenes.retarget.retarget), which
    keeps its own length and is named by its kind.

    Each clip fades in from the rest pose (make_motion; a precomputed Motion here, the way clips fade out) and,
    except the last, fades back out to it over its final `blend_frames`, so that every seam joins rest to rest and
    the sequence stays C¹. Fading scales joint angles and the root's vertical excursion by w and the root's
    horizontal velocity by w (its position is the running integral), so a walk slows to a halt instead of
    sliding back; the next clip starts where the previous one stopped. Clip k uses seed + k.
    """
    skel = skel or default_skeleton()
    kinds = [c for c in clips if isinstance(c, str)]
    fixed = [c.n_frames for c in clips if isinstance(c, Motion)]
    share = (n_frames - settle_frames - sum(fixed)) // max(len(kinds), 1)
    if not clips or (kinds and share < 2 * blend_frames + 1) or min(fixed, default=share) < 2 * blend_frames + 1:
        raise ValueError(f"{n_frames} frames with {settle_frames} settle frames leave {share} per clip for "
                         f"{len(clips)} clip(s); each needs more than 2 * blend_frames = {2 * blend_frames}")
    if not kinds and settle_frames + sum(fixed) != n_frames:
        raise ValueError(f"{n_frames} frames, but {settle_frames} settle frames and the clips take "
                         f"{settle_frames + sum(fixed)}")
    lengths = [c.n_frames if isinstance(c, Motion) else share for c in clips]
    if kinds:   # the last procedural clip takes the remainder
        last_kind = max(k for k, c in enumerate(clips) if isinstance(c, str))
        lengths[last_kind] = n_frames - settle_frames - sum(lengths) + share
    names = [c if isinstance(c, str) else c.kind for c in clips]
    rest_root = skel.joint_offsets[0]
    parts = [make_motion("rest", settle_frames, fps, seed, 0, blend_frames, skel)] if settle_frames else []
    clip = [np.zeros(settle_frames, dtype=np.int64)]
    offset = np.zeros(3)
    for k, (entry, length) in enumerate(zip(clips, lengths)):
        m = entry if isinstance(entry, Motion) else make_motion(entry, length, fps, seed + k, 0, blend_frames, skel)
        root, root_velocity = m.root_position - rest_root, m.root_velocity.copy()
        angles, rates = m.joint_angles.copy(), m.joint_angle_rates.copy()
        if isinstance(entry, Motion):
            w, dw, _ = fade_in(np.arange(length) / fps, blend_frames / fps)
            root, root_velocity, angles, rates = _fade(root, root_velocity, angles, rates, w, dw, fps)
        if k < len(clips) - 1:
            w, dw, _ = fade_in((length - 1 - np.arange(length)) / fps, blend_frames / fps)
            # time runs toward the end of the clip: the weight's derivative changes sign
            root, root_velocity, angles, rates = _fade(root, root_velocity, angles, rates, w, -dw, fps)
        parts.append(Motion(names[k], float(fps), seed + k, 0, blend_frames, root + rest_root + offset,
                            root_velocity, angles, rates))
        clip.append(np.full(length, k + 1, dtype=np.int64))
        offset = offset + root[-1] * np.array([1.0, 0.0, 1.0])
    motion = Motion("+".join(names), float(fps), int(seed), int(settle_frames), int(blend_frames),
                    *(np.concatenate([getattr(p, name) for p in parts])
                      for name in ("root_position", "root_velocity", "joint_angles", "joint_angle_rates")))
    return ClipSequence(motion, np.concatenate(clip), ("settle", *names))


def at_rest(n_frames: int, fps: float, skel: Skeleton | None = None) -> ClipSequence:
    """`n_frames` at the rest pose, clip index 0 ("settle"): a garment's settle sequence, the cloth settling on the
    still body once for every library window (scenes.garment_scene), whose frame 0 is this pose."""
    skel = skel or default_skeleton()
    if n_frames < 1:
        raise ValueError(f"a settle sequence needs a frame or more, got {n_frames}")
    zeros = np.zeros((n_frames, skel.n_parts, 3))
    motion = Motion("rest", float(fps), 0, n_frames, 1, np.tile(skel.joint_offsets[0], (n_frames, 1)),
                    np.zeros((n_frames, 3)), zeros, zeros.copy())
    return ClipSequence(motion, np.zeros(n_frames, dtype=np.int64), ("settle",))


def play_window(clip: Motion, blend_frames: int, hold_frames: int, skel: Skeleton | None = None) -> ClipSequence:
    """One motion-capture window the paper's way, from the rest pose at frame 0 (where the garment's settle
    sequence, at_rest, leaves the cloth: the settle at rest is the same for every window, so it is simulated once):
    the rest pose blended over `blend_frames` into the clip's first pose, held there `hold_frames` (the cloth
    settles on the posed body), then the clip as it is, at full amplitude from its first frame (a raw Motion at its
    fps, scenes.retarget.retarget). The blend moves joint angles and the root by a quintic smoothstep, so it starts
    and ends at rest; where the blended pose would put a foot through the floor the root is lifted (ground_lift).
    The frames before the clip are the sequence's lead-in, clip index 0 ("settle"), as a program's settle period
    is."""
    skel = skel or default_skeleton()
    fps = clip.fps
    if blend_frames < 1 or hold_frames < 0 or clip.n_frames < 2:
        raise ValueError(f"a window needs blend_frames >= 1, hold_frames >= 0 and a clip of 2 frames or more; got "
                         f"{blend_frames}, {hold_frames}, {clip.n_frames}")
    rest_root = skel.joint_offsets[0]
    w, dw, _ = fade_in(np.arange(blend_frames) / fps, (blend_frames - 1) / fps if blend_frames > 1 else 1 / fps)
    first_angles, first_root = clip.joint_angles[0], clip.root_position[0] - rest_root
    angles = w[:, None, None] * first_angles
    rates = dw[:, None, None] * first_angles
    root = rest_root + w[:, None] * first_root
    root_velocity = dw[:, None] * first_root
    # Rest and the clip's first pose have their height already: the lift less its values at the blend's two ends,
    # taken in by w (a smoothed lift is not exactly 0 there), so that the blend starts and ends exactly where the
    # rest and the clip are.
    lift, lift_rate = ground_lift(skel, root, root_velocity, angles, rates, fps)
    root[:, 1] += lift - (1.0 - w) * lift[0] - w * lift[-1]
    root_velocity[:, 1] += lift_rate + dw * (lift[0] - lift[-1])
    still = lambda n, value: np.broadcast_to(value, (n, *value.shape)).copy()     # noqa: E731
    segments = [
        (root, root_velocity, angles, rates),
        (still(hold_frames, clip.root_position[0]), np.zeros((hold_frames, 3)), still(hold_frames, first_angles),
         np.zeros((hold_frames, *first_angles.shape))),
        (clip.root_position, clip.root_velocity, clip.joint_angles, clip.joint_angle_rates)]
    lead_in = blend_frames + hold_frames
    motion = Motion(clip.kind, float(fps), clip.seed, lead_in, int(blend_frames),
                    *(np.concatenate([segment[k] for segment in segments]) for k in range(4)))
    return ClipSequence(motion, np.repeat([0, 1], [lead_in, clip.n_frames]).astype(np.int64), ("settle", clip.kind))


def _fade(root: np.ndarray, root_velocity: np.ndarray, angles: np.ndarray, rates: np.ndarray, w: np.ndarray,
          dw: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A clip (root relative to the rest root) faded toward rest by weight w (F,) with time derivative dw: angles
    and the root's height scaled by w, its horizontal velocity too, its horizontal position re-integrated from
    that velocity (trapezoid rule) from the clip's first frame."""
    rates = w[:, None, None] * rates + dw[:, None, None] * angles
    angles = w[:, None, None] * angles
    root_velocity[:, 1] = w * root_velocity[:, 1] + dw * root[:, 1]
    root[:, 1] *= w
    root_velocity[:, [0, 2]] *= w[:, None]
    steps = 0.5 * (root_velocity[1:, [0, 2]] + root_velocity[:-1, [0, 2]]) / fps
    root[:, [0, 2]] = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return root, root_velocity, angles, rates
