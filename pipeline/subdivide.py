"""Stage `subdivide`: Loop-subdivide the low-res rest mesh and compute the high-res harmonic test functions.

    python -m pipeline.subdivide MESH OUT.h5 [--settings SETTINGS.json] [--levels 2] [--vertices-per-harmonic 40]
                                 [--quiet]

MESH is an OBJ/PLY mesh or an HDF5 artifact holding one (e.g. scene.h5's `rest/`). OUT.h5 holds the subdivision
matrix S (high-res = S @ low-res), the subdivided rest mesh and the harmonic basis; docs/artifacts.md
lists every dataset. With --settings (a scene's resolved settings.json), `high_res.subdivision_levels` and
`high_res.vertices_per_harmonic` are the defaults of --levels and --vertices-per-harmonic.

Each level of Loop subdivision quadruples the faces, and the harmonic basis costs time and memory in proportion
to vertices x harmonics, so the stage works out the cost from the mesh before it starts: it says what the run
will take (unless --quiet) and refuses a run beyond a ceiling of vertices or of the eigensolver's memory, naming
the flags to change.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from geometry.mesh import unique_edges
from pipeline.artifacts.subdiv import Harmonics, Subdivision, write_subdiv
from pipeline.core.cli import add_quiet, parse_with_settings, run
from pipeline.core.config import LEARNING_ONLY
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import mesh_fingerprint
from pipeline.core.meshio import load_mesh

MAX_VERTICES = 1_000_000           # subdivided vertices: beyond the simulation and dataset this pipeline is sized for
MAX_EIGENSOLVER_BYTES = 16 * 2**30  # ARPACK keeps a Lanczos basis of 2 K + 1 vectors of V_high float64
# harmonic_basis takes about this long per vertex and harmonic (measured on 2 CPU cores: 2k to 31k vertices,
# V / 40 harmonics, 1e-5 to 1.7e-5 s)
SECONDS_PER_VERTEX_HARMONIC = 1.5e-5


@dataclasses.dataclass(frozen=True)
class Cost:
    """What subdividing a mesh and computing its harmonics will take."""
    vertices: int                  # after subdivision
    harmonics: int
    eigensolver_bytes: int
    seconds: float

    def __str__(self) -> str:
        return (f"{self.vertices:,} vertices, {self.harmonics:,} harmonics: about {self.seconds:.0f} s and "
                f"{self.eigensolver_bytes / 2**20:,.0f} MiB")


def subdivision_cost(n_vertices: int, faces: np.ndarray, levels: int, vertices_per_harmonic: int) -> Cost:
    """The cost of `levels` Loop subdivisions of a mesh, from its counts: each level adds a vertex per edge, and
    splits every edge in two and every face into four, adding three edges inside each face."""
    vertices, edges, n_faces = n_vertices, len(unique_edges(faces)), len(faces)
    for _ in range(levels):
        vertices, edges, n_faces = vertices + edges, 2 * edges + 3 * n_faces, 4 * n_faces
    harmonics = harmonic_count(vertices, vertices_per_harmonic)
    return Cost(vertices, harmonics, 8 * vertices * (2 * harmonics + 1),
                SECONDS_PER_VERTEX_HARMONIC * vertices * harmonics)


def check_cost(cost: Cost, levels: int, vertices_per_harmonic: int) -> None:
    """Refuse a run beyond the ceilings, naming the flags that set its size."""
    if cost.vertices > MAX_VERTICES:
        raise PipelineError(f"--levels {levels} would make {cost.vertices:,} vertices (at most {MAX_VERTICES:,}): "
                            f"use fewer levels")
    if cost.eigensolver_bytes > MAX_EIGENSOLVER_BYTES:
        raise PipelineError(f"--levels {levels} --vertices-per-harmonic {vertices_per_harmonic}: {cost.harmonics:,} "
                            f"harmonics of {cost.vertices:,} vertices need {cost.eigensolver_bytes / 2**30:,.0f} GiB "
                            f"(at most {MAX_EIGENSOLVER_BYTES // 2**30}): use fewer levels or more vertices per "
                            f"harmonic")


def _int_in(minimum: int, maximum: int | None = None):
    def parse(text: str) -> int:
        value = int(text)
        if value < minimum or (maximum is not None and value > maximum):
            most = "" if maximum is None else f" and <= {maximum}"
            raise argparse.ArgumentTypeError(f"must be >= {minimum}{most}, got {value}")
        return value
    return parse


def flags_from_settings(settings: dict) -> dict[str, Any]:
    high_res = settings["high_res"]
    return {"levels": high_res["subdivision_levels"], "vertices_per_harmonic": high_res["vertices_per_harmonic"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.subdivide", description=__doc__.splitlines()[0])
    parser.add_argument("mesh", help="low-res rest mesh: .obj/.ply or an .h5 artifact")
    parser.add_argument("out", help="output subdiv.h5")
    # 10 levels multiply the faces by a million: even one triangle has half a million vertices then
    parser.add_argument("--levels", type=_int_in(0, 10), default=2, help="Loop subdivision levels (paper: 2)")
    parser.add_argument("--vertices-per-harmonic", type=_int_in(1), default=40,
                        help="K = ceil(high-res vertices / this) harmonic test functions (paper: 40)")
    add_quiet(parser)
    args = parse_with_settings(parser, argv, flags_from_settings, unread=LEARNING_ONLY)

    # Loaded and costed before anything is printed, so that bad input prints nothing but its error line.
    low_vertices, low_faces = load_mesh(args.mesh)
    cost = subdivision_cost(len(low_vertices), low_faces, args.levels, args.vertices_per_harmonic)
    check_cost(cost, args.levels, args.vertices_per_harmonic)
    if not args.quiet:
        print(f"subdivide: Loop x{args.levels} of {len(low_vertices):,} vertices: {cost}", file=sys.stderr)
    with tqdm(total=3, desc="subdivide", unit="step", disable=args.quiet) as progress:
        progress.set_postfix_str(f"Loop x{args.levels} of {len(low_vertices)} vertices")
        subdivision, high_faces = loop_subdivide(low_vertices, low_faces, args.levels)
        high_vertices = subdivision @ low_vertices
        progress.update()
        n_harmonics = harmonic_count(len(high_vertices), args.vertices_per_harmonic)
        progress.set_postfix_str(f"{n_harmonics} harmonics of {len(high_vertices)} vertices")
        try:
            basis, eigenvalues, mass = harmonic_basis(high_vertices, high_faces, n_harmonics)
        except ValueError as err:  # only a count the mesh cannot supply gets here: the mesh was validated
            raise PipelineError(f"{args.mesh}: {err} (--vertices-per-harmonic {args.vertices_per_harmonic})") from None
        progress.update()
        progress.set_postfix_str("writing")
        config = {"mesh": str(args.mesh), "levels": args.levels, "vertices_per_harmonic": args.vertices_per_harmonic}
        write_subdiv(args.out, config, args.levels, args.vertices_per_harmonic, len(low_vertices),
                     Subdivision(subdivision, high_vertices, high_faces), Harmonics(basis, eigenvalues, mass),
                     mesh_fingerprint(low_vertices, low_faces))
        progress.update()


if __name__ == "__main__":
    run(main)
