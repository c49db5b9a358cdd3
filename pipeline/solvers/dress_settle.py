"""The settle that takes a garment placed on the rest-pose mannequin (scenes.dressing) clear of the body before
frame 0, with the XPBD cloth solver: gravity, body collision and the scene's pins, in STAGES stages. Over the
stages the body grows from RADIUS_START of its capsules' radii to all of them, so cloth that starts inside a limb
is pushed out the way it is nearest to leave rather than caught at full depth; and the rest lengths are eased in
from those of the cloth as each stage starts to the file's, so the stretch the push-out made relaxes without a
jolt. A vertex deep enough to stay inside even the shrunken body is pushed to the nearest surface, as any contact."""
from __future__ import annotations

import dataclasses

import numpy as np

from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings

STAGES = 4
RADIUS_START = 0.5


def settle_on_body(placed: np.ndarray, faces: np.ndarray, pinned: np.ndarray, capsules: np.ndarray,
                   radii: np.ndarray, settings: SolverSettings, frames: int, device: str = "cpu"
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The cloth after the settle (V, 3) float64, and each stage's last frame (STAGES, V, 3) (what the dress
    stage checks against the body and stores). `frames` are shared by the stages (at least one each);
    `capsules` (N, 2, 3) the body's capsules at rest, `radii` (N, 2); the pinned vertices stay where `placed` has
    them; the scene's solver `settings`, with body collision on."""
    frames_per_stage = max(1, frames // STAGES)
    settings = dataclasses.replace(settings, body_collision=True)
    x = np.asarray(placed, dtype=np.float64)
    inputs = FrameInputs(pin_targets=x[pinned][None] if len(pinned) else None, capsules=capsules[None])
    stages = []
    for stage in range(1, STAGES + 1):
        t = stage / STAGES
        rest = (1.0 - t) * x + t * placed
        model = ClothModel(rest, faces, settings, pinned,
                           capsule_radii=(RADIUS_START + (1.0 - RADIUS_START) * t) * radii)
        solver = ClothSolver(model, device, initial_inputs=FrameInputs(capsules=capsules[None]),
                             initial_positions=x)
        for _ in range(frames_per_stage):
            solver.step(solver.state, inputs)
        x = solver.state.read_positions()
        stages.append(x)
    return x, np.stack(stages)
