"""The XPBD cloth solver: vertex-centric Jacobi distance constraints (stretch with a compression allowance,
bending links), pins, continuous body collision against capsules, vertex-triangle self-collision, and the
harmonic projection that holds a high-res run to a low-res one."""
from sim.xpbd.solver import ClothSolver, SolverSettings, UnstableSimulation, harmonic_constraint

__all__ = ["ClothSolver", "SolverSettings", "UnstableSimulation", "harmonic_constraint"]
