"""The quasi-static volumetric FEM solver: a tet mesh of stable Neo-Hookean material whose driven nodes follow
per-frame targets (the bones of a hand) and whose other nodes come to rest at each frame's energy minimum (Newton's
method, preconditioned CG, line search), with a surface embedded in the tets as what a run stores.

In the shape of `sim.solver`: `model` (FemModel: nodes, tets, settings, driven nodes, the embedded surface),
`solver` (FemSolver, FemState, FemInputs, FrameReport). `settings` (FemSettings: material, stopping rule),
`neohookean` (the energy density, its stress and the analytic eigensystem of its Hessian, Warp functions),
`energy` (ElasticEnergy: per-world energies, gradient and the assembled Hessian, warp.sparse)."""
from sim.fem.energy import ElasticEnergy
from sim.fem.model import FemModel
from sim.fem.settings import FemSettings
from sim.fem.solver import FemInputs, FemSolver, FemState, FrameReport

__all__ = ["ElasticEnergy", "FemInputs", "FemModel", "FemSettings", "FemSolver", "FemState", "FrameReport"]
