"""The shape every solver in `sim` has, after NVIDIA Newton's Model / State / Control split.

- a **model**: what never changes over a run (rest mesh, constraints, pinned vertices, collision shapes, the
  settings), host-side arrays checked when the model is made;
- a **state**: what a frame advances (positions, velocities), device arrays made by the solver;
- **inputs**: the kinematic drive of one frame at its end (pin targets, body, targets of other runs): Newton's
  Control.

A solver is built from its model, a device, the number of worlds (independent copies of the model stepped
together, each with its own inputs) and the inputs at frame 0; it makes the one state it advances
(`solver.state`), and `step(state, inputs)` advances that state by one frame. `sim.xpbd` is one (ClothModel,
ClothState, FrameInputs, ClothSolver); a second solver (the volumetric FEM of the hand) goes beside it as
`sim/<name>/` with its own three types, and the simulate stage steps either the same way
(`pipeline/solvers/` turns a scene's artifacts into a solver's model and inputs).
"""
from __future__ import annotations

from typing import Protocol, TypeVar

import numpy as np


class WorldState(Protocol):
    """What the stage reads of any solver's state after a step."""

    def read_world_positions(self) -> np.ndarray:
        """(B, V, 3) float32 copy of the positions a run stores (its output mesh's vertices), world by world."""


Model = TypeVar("Model")
State = TypeVar("State", bound=WorldState)
Inputs = TypeVar("Inputs", contravariant=True)


class Solver(Protocol[Model, State, Inputs]):
    model: Model       # what it was built from
    worlds: int        # copies of the model stepped together
    state: State       # the state this solver advances, made with the solver (its device arrays stay fixed)

    def step(self, state: State, inputs: Inputs) -> None:
        """Advance `state` by one frame to the inputs at the end of the frame. Raises UnstableSimulation."""


class UnstableSimulation(RuntimeError):
    """A step went wrong in a way no later step can repair; `world` and `substep` (the step within the frame) say
    where first, `cause` what happened, in words."""

    def __init__(self, world: int, substep: int, cause: str):
        super().__init__(f"world {world}, substep {substep}")
        self.world, self.substep, self.cause = world, substep, cause
