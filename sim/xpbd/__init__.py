"""The XPBD cloth solver: vertex-centric Jacobi distance constraints (stretch with a compression allowance,
bending links), pins, continuous body collision against capsules, vertex-triangle self-collision, and the
harmonic projection that holds a high-res run to a low-res one.

In the shape of `sim.solver` (Newton's Model / State / Control): `model` (ClothModel: rest mesh, settings, pins,
harmonic constraint, the body's capsule radii), `solver` (ClothSolver: the device layout and frame stepping,
`step(state, inputs)`; ClothState, FrameInputs). Host side: `settings` (SolverSettings), `constraints` (constraint
assembly, numpy), `clearance` (shapes moved clear of the body outside a step: a high-res run's targets). Kernels:
`kernels` (integration, distance constraints, harmonic projection), `body_contact` (capsules), `self_contact`
(vertex-triangle search and response) and `contact_sweep` (the Jacobi sweep with both fused in)."""
from sim.solver import UnstableSimulation
from sim.xpbd.constraints import DistancePairs, HarmonicConstraint, cloth_constraints, harmonic_constraint
from sim.xpbd.model import ClothModel
from sim.xpbd.settings import SolverSettings
from sim.xpbd.solver import ClothSolver, ClothState, FrameInputs

__all__ = ["ClothModel", "ClothSolver", "ClothState", "DistancePairs", "FrameInputs", "HarmonicConstraint",
           "SolverSettings", "UnstableSimulation", "cloth_constraints", "harmonic_constraint"]
