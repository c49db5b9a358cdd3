"""Stage `subdivide`: Loop-subdivide the low-res rest mesh and compute the high-res harmonic test functions.

    python -m pipeline.subdivide MESH OUT.h5 [--levels 2] [--quiet]

MESH is an OBJ/PLY mesh or an HDF5 artifact holding one (e.g. scene.h5's `rest/`). OUT.h5 holds the subdivision
matrix S (high-res = S @ low-res), the subdivided rest mesh and the harmonic basis; docs/artifacts_subdiv.md
lists every dataset.
"""
from __future__ import annotations

import argparse
from typing import Sequence

import numpy as np
from tqdm import tqdm

from pipeline.artifacts import atomic_h5, write_csr
from pipeline.cli import add_quiet, run
from pipeline.meshio import load_mesh
from sim.harmonics import harmonic_basis, harmonic_count
from sim.loop import loop_subdivide


def _levels(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.subdivide", description=__doc__.splitlines()[0])
    parser.add_argument("mesh", help="low-res rest mesh: .obj/.ply or an .h5 artifact")
    parser.add_argument("out", help="output subdiv.h5")
    parser.add_argument("--levels", type=_levels, default=2, help="Loop subdivision levels (paper: 2)")
    add_quiet(parser)
    args = parser.parse_args(argv)

    # Loaded before the progress bar starts, so that bad input prints nothing but its error line.
    low_vertices, low_faces = load_mesh(args.mesh)
    with tqdm(total=3, desc="subdivide", unit="step", disable=args.quiet) as progress:
        progress.set_postfix_str(f"Loop x{args.levels} of {len(low_vertices)} vertices")
        subdivision, high_faces = loop_subdivide(low_vertices, low_faces, args.levels)
        high_vertices = subdivision @ low_vertices
        progress.update()
        n_harmonics = harmonic_count(len(high_vertices))
        progress.set_postfix_str(f"{n_harmonics} harmonics of {len(high_vertices)} vertices")
        basis, eigenvalues, mass = harmonic_basis(high_vertices, high_faces, n_harmonics)
        progress.update()
        progress.set_postfix_str("writing")
        config = {"mesh": str(args.mesh), "levels": args.levels}
        with atomic_h5(args.out, "subdivide", config) as f:
            f.attrs["levels"] = args.levels
            f.attrs["n_low_vertices"] = len(low_vertices)
            f.attrs["n_high_vertices"] = len(high_vertices)
            f.attrs["n_harmonics"] = n_harmonics
            write_csr(f, "S", subdivision)
            f.create_dataset("vertices", data=high_vertices.astype(np.float64))
            f.create_dataset("faces", data=high_faces.astype(np.int32))
            harmonics = f.create_group("harmonics")
            harmonics.attrs["laplacian"] = "cotangent"
            harmonics.attrs["mass"] = "barycentric lumped"
            harmonics.create_dataset("basis", data=basis)
            harmonics.create_dataset("eigenvalues", data=eigenvalues)
            harmonics.create_dataset("mass", data=mass)
        progress.update()


if __name__ == "__main__":
    run(main)
