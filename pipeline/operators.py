"""Stage `operators`: convolution tables and the pooling hierarchy of one mesh (paper 3.1-3.2).

    python -m pipeline.operators MESH OUT.h5 [--settings SETTINGS.json] [--conv RC13,EC13,SP13,SPD13]
                                            [--levels 10] [--quadric-threshold 0.01] [--quiet]

MESH is an OBJ/PLY/OFF/STL file or a pipeline HDF5 artifact holding `vertices` and `faces` (root, `rest/` or
`levels/0/`); OUT.h5 carries on such an artifact's `source_mesh` (the low-res rest mesh it derives from), so that
`train` can tell operators of another mesh from the dataset's. The layout of OUT.h5 is documented in
docs/artifacts.md (section "operators.h5"). With --settings (a scene's resolved settings.json), `operators.conv`
and `operators.levels` are the defaults of --conv and --levels.
"""
from __future__ import annotations

import argparse
import math
import sys
from typing import Any, Sequence

import h5py

from meshops import Level, build_operators, parse_conv_kinds
from meshops.levels import DEFAULT_CONV, DEFAULT_POOLING_STEPS, DEFAULT_QUADRIC_THRESHOLD
from pipeline.artifacts.operators import write_operators
from pipeline.core.cli import add_quiet, parse_with_settings, run
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import source_mesh_of
from pipeline.core.meshio import load_mesh


# Each pooling step keeps about 60 % of the vertices or fewer: past 30 steps a mesh of any size this pipeline can
# make has long been collapsed as far as it goes, and further steps would only repeat its last level.
MAX_LEVELS = 30


def flags_from_settings(settings: dict) -> dict[str, Any]:
    return {"conv": settings["operators"]["conv"], "levels": settings["operators"]["levels"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.operators", description=__doc__.split("\n\n")[0])
    parser.add_argument("mesh", help="input mesh: .obj/.ply/.off/.stl or an .h5 artifact")
    parser.add_argument("out", help="output operators .h5")
    parser.add_argument("--conv", default=",".join(DEFAULT_CONV),
                        help="comma-separated KIND+LENGTH tables, KIND in RC, EC, SP, SPD (default %(default)s)")
    parser.add_argument("--levels", type=int, default=DEFAULT_POOLING_STEPS,
                        help="pooling steps: meshes levels/0..levels/N are written (default %(default)s)")
    parser.add_argument("--quadric-threshold", type=float, default=DEFAULT_QUADRIC_THRESHOLD,
                        help="quadric error, in squared mean edge lengths, past which a pooling pass stops once "
                             "below 60%% of its vertices (default %(default)s)")
    add_quiet(parser)
    args = parse_with_settings(parser, argv, flags_from_settings)

    conv = _parse_conv(args.conv)
    if not 0 <= args.levels <= MAX_LEVELS:
        raise PipelineError(f"--levels must be >= 0 and <= {MAX_LEVELS}, got {args.levels}")
    if not 0 <= args.quadric_threshold < math.inf:
        raise PipelineError(f"--quadric-threshold must be finite and >= 0, got {args.quadric_threshold}")
    vertices, faces = load_mesh(args.mesh)
    levels = build_operators(vertices, faces, conv, args.levels, args.quadric_threshold,
                             progress=None if args.quiet else _report)
    config = {"mesh": args.mesh, "conv": conv, "levels": args.levels, "quadric_threshold": args.quadric_threshold}
    write_operators(args.out, levels, config, source_mesh_of(args.mesh) if h5py.is_hdf5(args.mesh) else None)


def _parse_conv(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    try:
        parse_conv_kinds(names)
    except ValueError as err:
        raise PipelineError(f"--conv {text!r}: {err}") from None
    return names


def _report(index: int, level: Level) -> None:
    seconds = sum(level.seconds.values())
    print(f"level {index}: {len(level.vertices)} vertices, {len(level.faces)} faces, {seconds:.2f} s",
          file=sys.stderr)


if __name__ == "__main__":
    run(main)
