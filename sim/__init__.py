"""Physics solvers, side by side (one subpackage each, like NVIDIA Newton's `solvers/`): today `sim.xpbd`, the
XPBD cloth solver. Each has the shape of `sim.solver`: a static model, the state a frame advances and per-frame
inputs; a solver is built from its model and makes the state it advances, and `step(state, inputs)` advances it one
frame. A solver knows nothing of Snakemake, HDF5 layouts, torch or where a body comes from: it takes meshes,
settings and per-frame kinematic inputs as arrays."""
