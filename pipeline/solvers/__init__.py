"""The solvers' adapters: what turns a scene's artifacts into a solver's model and per-frame inputs, one module per
solver kind (`xpbd`: the cloth), looked up by the scene's `solver.kind` (`registry`); `level` is the shape of an
adapter, which the simulate stage steps without knowing the solver."""
