"""The shape every solver in `sim` has: it makes the state it advances, and `step(state, inputs)` advances that
state by one frame, driven by the frame's kinematic inputs. `sim.xpbd.ClothSolver` is one (state: cloth positions
and velocities; inputs: pin targets, harmonic target, capsules); a second solver (the volumetric FEM of the hand)
goes beside it as `sim/<name>/` with its own state and inputs types, so a stage steps either the same way."""
from __future__ import annotations

from typing import Protocol, TypeVar

State = TypeVar("State")
Inputs = TypeVar("Inputs", contravariant=True)


class Solver(Protocol[State, Inputs]):
    state: State  # the state this solver advances, made with the solver (its device arrays stay fixed)

    def step(self, state: State, inputs: Inputs) -> None:
        """Advance `state` by one frame to the inputs at the end of the frame."""
