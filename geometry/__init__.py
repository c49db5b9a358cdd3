"""Triangle-mesh geometry shared by the solvers, the scene content, the operator builder and the stages: mesh
checks and topology, Loop subdivision as a sparse operator, the cotangent Laplacian and harmonic basis, rigid
transforms. Plain numpy/scipy: no Warp, no torch, no HDF5."""
