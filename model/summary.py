"""Print a network's layer table and learnable-parameter count.

    python -m model.summary "D62 D124 D248 D D248 D_3 D248" --conv RC13 [--pool max] [--width 0.5]
    python -m model.summary "U208 U U208 U U208 U U208 U104 U52 U3" --conv RC13 --in-channels 208 \\
        --operators results/flag/operators.h5

An encoder-decoder (D tokens) needs no mesh: its parameters do not depend on it. A decoder (U tokens) has a fully
connected layer onto its coarsest level, so it takes the mesh's operators file (only the vertex count of each
level `levels/{i}/vertices` is read). With --operators, the table also lists each level's vertex count.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Sequence

from model.architecture import ArchitectureError, parse_architecture
from model.networks import MeshNetwork, NetworkSpec, build_network


def layer_table(net: MeshNetwork, vertex_counts: Sequence[int] | None = None) -> list[tuple[str, ...]]:
    """Rows (block, operation, level, vertices, channels, parameters) of every step the network runs."""
    rows = []
    channels = net.in_channels if hasattr(net, "in_channels") else net.n_inputs
    skip_channels: list[int] = []
    for step in net.steps:
        params = ""
        if step.op == "conv":
            conv = net.convs[step.index]
            operation = f"conv L={conv.size}"
            shape = f"{conv.in_channels} -> {conv.out_channels}"
            params = _count(conv)
            channels = conv.out_channels
        elif step.op == "linear":
            operation = "fully connected"
            shape = f"{net.n_inputs} -> {net.coarse_vertices} x {net.coarse_channels}"
            params = _count(net.linear)
            channels = net.coarse_channels
        elif step.op == "norm":
            operation, shape = "instance norm + leaky ReLU", str(channels)
        elif step.op == "save":
            operation, shape = "keep for skip", str(channels)
            skip_channels.append(channels)
        elif step.op == "pool":
            operation, shape = f"{net.pool_kind} pool -> level {step.level + 1}", str(channels)
        elif step.op == "unpool":
            operation, shape = f"unpool -> level {step.level}", str(channels)
        else:
            skip = skip_channels.pop()
            operation, shape = "concat skip", f"{channels} + {skip}"
            channels += skip
        vertices = str(vertex_counts[step.level]) if vertex_counts is not None else ""
        rows.append((step.block, operation, str(step.level), vertices, shape, f"{params:,}" if params else ""))
    return rows


def _count(module) -> int:
    return sum(p.numel() for p in module.parameters())


def format_table(rows: list[tuple[str, ...]], with_vertices: bool) -> str:
    header = ("block", "operation", "level", "vertices", "channels", "params")
    keep = [i for i in range(len(header)) if with_vertices or header[i] != "vertices"]
    table = [tuple(r[i] for i in keep) for r in [header, *rows]]
    widths = [max(len(r[i]) for r in table) for i in range(len(keep))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def operator_vertex_counts(path: str) -> list[int]:
    """Vertex count of each level of an operators file."""
    import h5py  # only the decoder and the optional column need a file

    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: operators file does not exist")
    with h5py.File(path, "r") as f:
        if "levels" not in f:
            raise ValueError(f"{path}: no 'levels' group (not an operators file)")
        return [int(f[f"levels/{i}/vertices"].shape[0]) for i in range(len(f["levels"]))]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m model.summary", description=__doc__.splitlines()[0])
    parser.add_argument("arch", help="architecture string, e.g. 'D62 D124 D248 D D248 D_3 D248'")
    parser.add_argument("--conv", default="RC13", help="convolution kind and size: RC|EC|SP|SPD + L (RC13)")
    parser.add_argument("--pool", default="avg", choices=["avg", "max"])
    parser.add_argument("--width", type=float, default=1.0, help="channel multiplier (paper: 1, 0.5, 0.25)")
    parser.add_argument("--in-channels", type=int, default=3, help="per-vertex inputs, or a decoder's scalars")
    parser.add_argument("--out-channels", type=int, default=3)
    parser.add_argument("--operators", help="operators.h5 of the mesh (required for a decoder)")
    args = parser.parse_args(argv)
    try:
        counts = operator_vertex_counts(args.operators) if args.operators else None
        coarse = None
        if args.arch.strip().startswith("U"):
            if counts is None:
                raise ArchitectureError("a decoder (U tokens) needs --operators: its fully connected layer maps "
                                        "onto the coarsest level's vertices")
            coarsest = parse_architecture(args.arch, "U").n_pooling
            if coarsest >= len(counts):
                raise ArchitectureError(f"'{args.arch}' needs {coarsest + 1} mesh levels, "
                                        f"{args.operators} has {len(counts)}")
            coarse = counts[coarsest]
        spec = NetworkSpec(args.arch, args.conv, args.pool, args.width, args.in_channels, args.out_channels, coarse)
        net = build_network(spec)
        if counts is not None and len(counts) < net.n_levels:
            raise ArchitectureError(f"'{net.arch}' needs {net.n_levels} mesh levels, {args.operators} has "
                                    f"{len(counts)}")
    except (ArchitectureError, ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(f"{net.kind}: {net.arch}  conv {args.conv}, {args.pool} pooling, width {args.width:g}, "
          f"{net.n_levels} mesh levels")
    print(format_table(layer_table(net, counts), counts is not None))
    print(f"learnable parameters: {net.parameter_count():,}")


if __name__ == "__main__":
    main()
