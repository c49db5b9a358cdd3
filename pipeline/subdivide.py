"""Stage `subdivide`: Loop-subdivide the low-res rest mesh and compute the high-res harmonic test functions.

    python -m pipeline.subdivide MESH OUT.h5 [--settings SETTINGS.json] [--levels 2] [--vertices-per-harmonic 40]
                                 [--quiet]

MESH is an OBJ/PLY mesh or an HDF5 artifact holding one (e.g. scene.h5's `rest/`). OUT.h5 holds the subdivision
matrix S (high-res = S @ low-res), the subdivided rest mesh and the harmonic basis; docs/artifacts.md
lists every dataset. With --settings (a scene's resolved settings.json), `high_res.subdivision_levels` and
`high_res.vertices_per_harmonic` are the defaults of --levels and --vertices-per-harmonic.
"""
from __future__ import annotations

import argparse
from typing import Any, Sequence

from tqdm import tqdm

from pipeline.artifacts.subdiv import Harmonics, Subdivision, write_subdiv
from pipeline.cli import add_quiet, parse_with_settings, run
from pipeline.errors import PipelineError
from pipeline.meshio import load_mesh
from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide


def _int_at_least(minimum: int):
    def parse(text: str) -> int:
        value = int(text)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value
    return parse


def flags_from_settings(settings: dict) -> dict[str, Any]:
    high_res = settings["high_res"]
    return {"levels": high_res["subdivision_levels"], "vertices_per_harmonic": high_res["vertices_per_harmonic"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.subdivide", description=__doc__.splitlines()[0])
    parser.add_argument("mesh", help="low-res rest mesh: .obj/.ply or an .h5 artifact")
    parser.add_argument("out", help="output subdiv.h5")
    parser.add_argument("--levels", type=_int_at_least(0), default=2, help="Loop subdivision levels (paper: 2)")
    parser.add_argument("--vertices-per-harmonic", type=_int_at_least(1), default=40,
                        help="K = ceil(high-res vertices / this) harmonic test functions (paper: 40)")
    add_quiet(parser)
    args = parse_with_settings(parser, argv, flags_from_settings)

    # Loaded before the progress bar starts, so that bad input prints nothing but its error line.
    low_vertices, low_faces = load_mesh(args.mesh)
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
                     Subdivision(subdivision, high_vertices, high_faces), Harmonics(basis, eigenvalues, mass))
        progress.update()


if __name__ == "__main__":
    run(main)
