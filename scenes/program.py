"""Motion programs: the motion of one training sequence as a seeded series of clips drawn from a pool.

The pool holds procedural kinds (scenes.motion.MOTION_KINDS) and precomputed raw Motions (motion capture,
scenes.retarget.retarget). `plan_program` draws, from one random generator, the order (the pool in a fresh random
order each round, so every clip plays before any repeats), each procedural clip's duration, speed, amplitude,
phase and seed, and each transition: a crossfade, or a fade out to rest, a short pause, and a fade in. A Motion
keeps its own length, speed and amplitude (it is data), and plays only where it fits whole.

`play_program` sums the clips under envelopes: clip k weighs W_k(t), a quintic smoothstep up over its fade-in, 1,
and down over its fade-out (scenes.motion.fade_in). A crossfade starts the next clip's fade-in where the previous
clip's fade-out starts, with the same length, so there W_k + W_k+1 = 1; at most two clips overlap. Joint angles
are Σ W_k a_k, a convex combination of poses within the joint limits and the rest pose (0, inside every limit box),
so they stay within the limits; rates are Σ (W_k a_k' + W_k' a_k), exact. The root's horizontal sway is Σ W_k s_k
(exact rate); its travel is the running integral (trapezoid rule) of Σ W_k v_k, so a walk slows to a halt when it
fades out and the next clip starts where it stopped. The root height keeps the lowest foot on the ground
(scenes.motion.ground_lift, faded in with the total weight as make_motion does). Weights and curves are C¹, and
so is the motion.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from scenes.motion import GROUND_SMOOTHING, ClipSequence, Motion, clip_curves, fade_in, ground_lift
from scenes.skeleton import Skeleton, default_skeleton

CLIP_SECONDS = (1.2, 2.5)    # duration of a procedural clip, fades included
SPEED = (0.8, 1.25)          # playback speed of a procedural clip
AMPLITUDE = (0.75, 1.15)     # scale of its joint angles and root excursion
PHASE_SECONDS = 4.0          # it starts this far into its curves at most
FADE = (0.6, 1.6)            # fade lengths, in blend_frames
CROSSFADE = 0.5              # chance that a transition is a crossfade rather than a pass through rest
PAUSE_SECONDS = 0.5          # longest rest between a fade-out and the next fade-in


@dataclass(frozen=True, eq=False)
class ProgramClip:
    """One clip of a program, in frames of the sequence: its fade-in starts at `start`, its fade-out ends at
    `end`; the clip that reaches the sequence's end does not fade out (fade_out 0, end = the sequence's frames)."""
    source: str | Motion    # a procedural kind, or a raw Motion at the program's fps
    start: int
    end: int
    fade_in: int
    fade_out: int
    speed: float = 1.0
    amplitude: float = 1.0
    phase: float = 0.0      # seconds into the procedural curves at `start`
    seed: int = 0           # of the procedural curves

    @property
    def name(self) -> str:
        return self.source if isinstance(self.source, str) else self.source.kind


def plan_program(pool: list[str | Motion], n_frames: int, settle_frames: int, blend_frames: int, fps: float,
                 rng: np.random.Generator) -> tuple[ProgramClip, ...]:
    """The clips of a program of `n_frames` frames that rests for `settle_frames`, drawn from `pool` with `rng`
    (see the module docstring). A Motion that does not fit before the end is replaced by a procedural clip of the
    pool (by `rest` if the pool has none)."""
    if not pool or n_frames <= settle_frames or blend_frames < 1 or fps <= 0:
        raise ValueError(f"a program needs clips, more frames than settle frames, blend_frames >= 1 and fps > 0; "
                         f"got {len(pool)} clip(s), {n_frames} frames, {settle_frames} settle, {blend_frames} blend")
    procedural = [c for c in pool if isinstance(c, str)] or ["rest"]
    clips: list[ProgramClip] = []
    order: list[int] = []
    start, fade = settle_frames, _fade_frames(rng, blend_frames)
    while start < n_frames:
        if not order:
            order = list(rng.permutation(len(pool)))
        source = pool[order.pop(0)]
        fade_out = _fade_frames(rng, blend_frames)
        if isinstance(source, Motion) and start + source.n_frames <= n_frames \
                and source.n_frames >= fade + fade_out + 1:
            clip = ProgramClip(source, start, start + source.n_frames, fade, fade_out)
        else:
            kind = source if isinstance(source, str) else procedural[rng.integers(len(procedural))]
            length = max(int(round(rng.uniform(*CLIP_SECONDS) * fps)), fade + fade_out + 1)
            clip = ProgramClip(kind, start, start + length, fade, fade_out, speed=rng.uniform(*SPEED),
                               amplitude=rng.uniform(*AMPLITUDE), phase=rng.uniform(0.0, PHASE_SECONDS),
                               seed=int(rng.integers(2 ** 31)))
            if clip.end > n_frames:   # it plays to the end (and on, into play_program's padding)
                clip = dataclasses.replace(clip, end=n_frames, fade_out=0)
        clips.append(clip)
        if clip.fade_out == 0:
            break
        if rng.random() < CROSSFADE:
            start, fade = clip.end - clip.fade_out, clip.fade_out
        else:
            start, fade = clip.end + int(rng.integers(0, int(PAUSE_SECONDS * fps) + 1)), _fade_frames(rng, blend_frames)
    return tuple(clips)


def play_program(program: tuple[ProgramClip, ...], n_frames: int, settle_frames: int, blend_frames: int,
                 seed: int, fps: float, skel: Skeleton | None = None) -> ClipSequence:
    """The motion of a planned program (see the module docstring). Each frame belongs to the clip of largest
    weight, a frame at rest between clips to the clip before, the frames before the first clip to `settle`."""
    skel = skel or default_skeleton()
    # Evaluate past the end so that smoothing the ground lift sees the true signal on both sides of every frame;
    # the clip that plays to the end plays on into the padding.
    total_frames = n_frames + int(np.ceil(4 * GROUND_SMOOTHING * fps))
    angles = np.zeros((total_frames, skel.n_parts, 3))
    rates = np.zeros_like(angles)
    sway, sway_rate, travel_rate = (np.zeros((total_frames, 3)) for _ in range(3))
    weights, weight_rates = np.zeros((len(program), total_frames)), np.zeros((len(program), total_frames))
    for k, clip in enumerate(program):
        frames = np.arange(clip.start, total_frames if clip.fade_out == 0 else clip.end)
        tau = (frames - clip.start) / fps
        w, dw, _ = fade_in(tau, clip.fade_in / fps)
        if clip.fade_out:
            down, ddown, _ = fade_in(tau - (clip.end - clip.fade_out - clip.start) / fps, clip.fade_out / fps)
            w, dw = w - down, dw - ddown
        clip_angles, clip_rates, clip_sway, clip_sway_rate, clip_travel = _raw(clip, skel, tau)
        angles[frames] += w[:, None, None] * clip_angles
        rates[frames] += w[:, None, None] * clip_rates + dw[:, None, None] * clip_angles
        sway[frames] += w[:, None] * clip_sway
        sway_rate[frames] += w[:, None] * clip_sway_rate + dw[:, None] * clip_sway
        travel_rate[frames] += w[:, None] * clip_travel
        weights[k, frames], weight_rates[k, frames] = w, dw
    steps = 0.5 * (travel_rate[1:] + travel_rate[:-1]) / fps
    root = skel.joint_offsets[0] + sway + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    root_velocity = sway_rate + travel_rate
    total, total_rate = weights.sum(axis=0), weight_rates.sum(axis=0)
    lift, lift_rate = ground_lift(skel, root, root_velocity, angles, rates, fps)
    root[:, 1] += total * lift
    root_velocity[:, 1] += total_rate * lift + total * lift_rate
    keep = slice(0, n_frames)
    names = tuple(clip.name for clip in program)
    motion = Motion("+".join(names), float(fps), int(seed), int(settle_frames), int(blend_frames), root[keep],
                    root_velocity[keep], angles[keep], rates[keep])
    return ClipSequence(motion, _clip_of_frames(weights[:, keep]), ("settle", *names))


def _fade_frames(rng: np.random.Generator, blend_frames: int) -> int:
    return max(1, int(round(rng.uniform(*FADE) * blend_frames)))


def _raw(clip: ProgramClip, skel: Skeleton, tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """A clip's raw joint angles and rates, horizontal sway and its rate, and travel velocity at clip times tau.
    A Motion's root travel is all travel (no sway); its height is the ground's business (ground_lift)."""
    if isinstance(clip.source, Motion):
        m, n = clip.source, len(tau)
        travel = m.root_velocity[:n] * np.array([1.0, 0.0, 1.0])
        return m.joint_angles[:n], m.joint_angle_rates[:n], np.zeros((n, 3)), np.zeros((n, 3)), travel
    curves = clip_curves(clip.source, skel, clip.seed, tau, clip.speed, clip.amplitude, clip.phase)
    return curves.angles, curves.rates, curves.offset, curves.offset_rate, np.broadcast_to(curves.travel, (len(tau), 3))


def _clip_of_frames(weights: np.ndarray) -> np.ndarray:
    """(F,) 1 + the clip of largest weight per frame; frames where no clip weighs keep the clip before (0 at the
    start: settle)."""
    playing = weights.max(axis=0) > 0
    label = np.where(playing, weights.argmax(axis=0) + 1, 0)
    last_playing = np.maximum.accumulate(np.where(playing, np.arange(len(label)), 0))
    return label[last_playing].astype(np.int64)
