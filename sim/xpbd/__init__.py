"""The XPBD cloth solver: vertex-centric Jacobi distance constraints (stretch with a compression allowance,
bending links), pins, continuous body collision against capsules, vertex-triangle self-collision, and the
harmonic projection that holds a high-res run to a low-res one.

`settings` (SolverSettings), `constraints` (host-side assembly, numpy), `solver` (ClothSolver: the device layout
and frame stepping, `step(state, inputs)` as in `sim.solver.Solver`), `kernels` (integration, distance constraints,
harmonic projection) and `collision` (the same steps with capsule and self-contacts fused in)."""
from sim.xpbd.constraints import DistancePairs, HarmonicConstraint, cloth_constraints, harmonic_constraint
from sim.xpbd.settings import SolverSettings
from sim.xpbd.solver import ClothSolver, ClothState, FrameInputs, UnstableSimulation

__all__ = ["ClothSolver", "ClothState", "DistancePairs", "FrameInputs", "HarmonicConstraint", "SolverSettings",
           "UnstableSimulation", "cloth_constraints", "harmonic_constraint"]
