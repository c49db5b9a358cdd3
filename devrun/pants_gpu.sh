#!/bin/bash
# GPU run of the pants scene's physics (paper profile) through the stage CLIs (no snakemake on the device).
set -e
S=${1:-devrun/pants_paper.json}; O=${2:-$OUT/pants}
mkdir -p $O
python -m pipeline.scene $S $O/scene.h5
python -m pipeline.subdivide $O/scene.h5 $O/subdiv.h5 --levels 2 --vertices-per-harmonic 40
python -m pipeline.simulate low $S $O/scene.h5 $O/sim_low.h5 --quiet
python -m pipeline.simulate high $S $O/scene.h5 $O/subdiv.h5 $O/sim_low.h5 $O/sim_high.h5 --quiet
python - $O <<'PY'
import sys, h5py, numpy as np
o = sys.argv[1]
for n in ("sim_low", "sim_high"):
    with h5py.File(f"{o}/{n}.h5") as f:
        ms = f["solve_ms"][2:]
        print(n, f["positions"].shape, "median ms/frame %.2f" % np.median(ms), "max residual",
              f["harmonic_residual"][()].max() if "harmonic_residual" in f else "-")
PY
