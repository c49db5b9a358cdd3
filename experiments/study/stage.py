"""Stage `study`: the generalisation study's table, plot and report from the evaluations of its grid.

    python -m experiments.study STUDY.h5 PLOT.png REPORT.md --point N VARIANT EVAL.h5 [--point ...]

Each point is a network with input variant VARIANT trained on the scene's first N training sequences and
evaluated on the test frames of those sequences and on the held-out motion (workflow/rules/study.smk makes them).
The table and plot answer a user's question: how much motion must be simulated before the network pays off on
motion it never saw? Loop subdivision alone (the predictor, no network) is the floor the network must beat; it
does not depend on N on the held-out motion.
"""
from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.artifacts.evaluation import read_errors, read_parameter_count
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, atomic_write
from viz.study_plot import study_plot

PAPER_UNIT = 1e-3
SPLITS = ("test", "held_out")


def gather(points: list[tuple[str, str, str]]) -> tuple[list[int], list[str], dict, dict[str, int]]:
    """Counts and variants (in the order first given), l1[who][split] as (variants, counts) arrays and each
    variant's parameter count."""
    counts, variants, parameters = [], [], {}
    for count, variant, _ in points:
        if not re.fullmatch(r"[0-9]+", count) or int(count) < 1 or not re.fullmatch(r"[A-Za-z0-9_]+", variant):
            raise PipelineError(f"--point {count} {variant}: N must be a positive integer and VARIANT letters, "
                                f"digits and _")
        counts += [int(count)] if int(count) not in counts else []
        variants += [variant] if variant not in variants else []
    counts.sort()
    l1 = {who: {split: np.full((len(variants), len(counts)), np.nan) for split in SPLITS}
          for who in ("network", "predictor")}
    for count, variant, path in points:
        errors = read_errors(path)
        parameters[variant] = read_parameter_count(path)
        missing = [s for s in SPLITS if s not in errors["network"]]
        if missing:
            raise PipelineError(f"{path}: no {' or '.join(missing)} errors (the study needs a held-out motion)")
        for who in l1:
            for split in SPLITS:
                l1[who][split][variants.index(variant), counts.index(int(count))] = errors[who][split]["l1"]
    if any(np.isnan(table).any() for splits in l1.values() for table in splits.values()):
        raise PipelineError("the points do not fill the grid of counts x variants: give every combination once")
    return counts, variants, l1, parameters


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.study", description=__doc__.splitlines()[0])
    parser.add_argument("table", help="study.h5 to write")
    parser.add_argument("plot", help="study.png to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--point", nargs=3, action="append", required=True, metavar=("N", "VARIANT", "EVAL.h5"))
    args = parser.parse_args(argv)
    cli.refuse_aliases({"STUDY.h5": args.table, "PLOT.png": args.plot, "REPORT.md": args.report},
                       {f"EVAL.h5 {i}": p for i, (_, _, p) in enumerate(args.point)})
    counts, variants, l1, parameters = gather(args.point)
    config = {"points": [list(p) for p in args.point]}
    with atomic_h5(args.table, "study", config) as f:
        f.create_dataset("counts", data=np.asarray(counts, dtype=np.int64))
        f.create_dataset("variants", data=np.array(variants, dtype="S"))
        for who, splits in l1.items():
            for split, table in splits.items():
                f.create_dataset(f"l1/{who}/{split}", data=table)
        f["l1"].attrs["meaning"] = ("split-wide L1 (eq. 4, scene units) of the network and of Loop subdivision alone "
                                    "(predictor), (variants, counts): rows follow `variants`, columns `counts` "
                                    "(training sequences)")
    png = study_plot(counts, variants, {split: l1["network"][split] / PAPER_UNIT for split in SPLITS},
                     {split: l1["predictor"][split] / PAPER_UNIT for split in SPLITS})
    with atomic_write(args.plot) as f:
        f.write(png)
    _write_report(Path(args.report), Path(args.plot), counts, variants, l1, parameters)


def _write_report(path: Path, plot: Path, counts: list[int], variants: list[str], l1: dict,
                  parameters: dict[str, int]) -> None:
    header = "| inputs | " + " | ".join(f"{n} seq." for n in counts) + " |"
    lines = ["# Generalisation study: error against the amount of training motion", "",
             "Each cell: L1 x 1e-3 of the network on the held-out motion (never trained on), and in brackets its "
             "gain over Loop subdivision alone (predictor / network: above 1, the network helps). Every network "
             "was trained for the same number of optimiser steps on the scene's first N training sequences; "
             "test = a random share of those sequences' frames. Networks: "
             + ", ".join(f"`{v}` {parameters[v]:,} parameters" for v in variants) + ".", "",
             f"![held-out and test L1 against training sequences]({os.path.relpath(plot, path.parent)})", ""]
    for split, title in (("held_out", "Held-out motion"), ("test", "Test frames of the trained motions")):
        network, predictor = l1["network"][split] / PAPER_UNIT, l1["predictor"][split] / PAPER_UNIT
        lines += [f"## {title}", "", header, "|---" * (len(counts) + 1) + "|"]
        for k, variant in enumerate(variants):
            cells = [f"{network[k, j]:.3f} ({predictor[k, j] / network[k, j]:.2f}x)" for j in range(len(counts))]
            lines.append(f"| `{variant}` | " + " | ".join(cells) + " |")
        lines += ["| Loop subdivision alone | " + " | ".join(f"{v:.3f}" for v in predictor[0]) + " |", ""]
    with atomic_write(path) as f:
        f.write(("\n".join(lines) + "\n").encode())

