"""Stage `study`: the generalisation study's table, plot and report from the evaluations of its points.

    python -m experiments.study STUDY.h5 PLOT.png REPORT.md --point LABEL VARIANT EVAL.h5 [--point ...]

Each point is a network with input variant VARIANT (experiments.study.points says what LABEL means: `n<N>`, a
dataset of the scene's first N training sequences; `f<N>`, the scene's dataset within N training frames; `oracle`,
the held-out motion trained on too), evaluated on the test frames and on the held-out motion
(workflow/rules/study.smk makes them); eval.h5 says how many frames it trained on. The table and plot answer a
user's question: how much motion must be simulated before the network pays off on motion it never saw, and how
close does it get to the oracle, which saw it? Loop subdivision alone (the predictor, no network) is the floor the
network must beat; it does not depend on the point on the held-out motion.
"""
from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from pipeline.artifacts.evaluation import read_errors, read_parameter_count, read_trained_frames
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_h5, atomic_write
from viz.study_plot import study_plot

PAPER_UNIT = 1e-3
SPLITS = ("test", "held_out")
LABEL = re.compile(r"[nf][1-9][0-9]*|oracle")


def gather(points: list[tuple[str, str, str]]) -> tuple[list[str], list[str], dict, np.ndarray, dict[str, int]]:
    """Labels (by kind, then frames trained on) and variants (in the order first given), l1[who][split] and the
    frames trained on as (variants, labels) arrays, and each variant's parameter count."""
    labels, variants, parameters = [], [], {}
    for label, variant, _ in points:
        if not LABEL.fullmatch(label) or not re.fullmatch(r"[A-Za-z0-9_]+", variant):
            raise PipelineError(f"--point {label} {variant}: LABEL must be n<N>, f<N> (N >= 1) or oracle and "
                                f"VARIANT letters, digits and _")
        labels += [label] if label not in labels else []
        variants += [variant] if variant not in variants else []
    labels.sort(key=lambda label: ("nfo".index(label[0]), int(label[1:]) if label[1:].isdigit() else 0))
    shape = (len(variants), len(labels))
    l1 = {who: {split: np.full(shape, np.nan) for split in SPLITS} for who in ("network", "predictor")}
    frames = np.zeros(shape, np.int64)
    for label, variant, path in points:
        errors = read_errors(path)
        parameters[variant] = read_parameter_count(path)
        missing = [s for s in SPLITS if s not in errors["network"]]
        if missing:
            raise PipelineError(f"{path}: no {' or '.join(missing)} errors (the study needs a held-out motion)")
        cell = variants.index(variant), labels.index(label)
        frames[cell] = read_trained_frames(path)
        for who in l1:
            for split in SPLITS:
                l1[who][split][cell] = errors[who][split]["l1"]
    if any(np.isnan(table).any() for splits in l1.values() for table in splits.values()):
        raise PipelineError("the points do not fill the grid of labels x variants: give every combination once")
    return labels, variants, l1, frames, parameters


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.study", description=__doc__.splitlines()[0])
    parser.add_argument("table", help="study.h5 to write")
    parser.add_argument("plot", help="study.png to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--point", nargs=3, action="append", required=True, metavar=("LABEL", "VARIANT", "EVAL.h5"))
    args = parser.parse_args(argv)
    cli.refuse_aliases({"STUDY.h5": args.table, "PLOT.png": args.plot, "REPORT.md": args.report},
                       {f"EVAL.h5 {i}": p for i, (_, _, p) in enumerate(args.point)})
    labels, variants, l1, frames, parameters = gather(args.point)
    config = {"points": [list(p) for p in args.point]}
    with atomic_h5(args.table, "study", config) as f:
        f.create_dataset("labels", data=np.array(labels, dtype="S"))
        f.create_dataset("variants", data=np.array(variants, dtype="S"))
        f.create_dataset("trained_frames", data=frames)
        for who, splits in l1.items():
            for split, table in splits.items():
                f.create_dataset(f"l1/{who}/{split}", data=table)
        f["l1"].attrs["meaning"] = ("split-wide L1 (eq. 4, scene units) of the network and of Loop subdivision alone "
                                    "(predictor), (variants, labels): rows follow `variants`, columns `labels` "
                                    "(n<N>: N training sequences, a dataset each; f<N>: the scene's dataset within N "
                                    "training frames; oracle: the held-out motion trained on too); `trained_frames` "
                                    "the same shape")
    kinds = [label[0] for label in labels]
    png = study_plot(frames, kinds, variants, {split: l1["network"][split] / PAPER_UNIT for split in SPLITS},
                     {split: l1["predictor"][split] / PAPER_UNIT for split in SPLITS})
    with atomic_write(args.plot) as f:
        f.write(png)
    _write_report(Path(args.report), Path(args.plot), labels, frames, variants, l1, parameters)


def _write_report(path: Path, plot: Path, labels: list[str], frames: np.ndarray, variants: list[str], l1: dict,
                  parameters: dict[str, int]) -> None:
    header = "| inputs | " + " | ".join(f"{_label_words(label)}, {frames[0, j]:,} frames"
                                          for j, label in enumerate(labels)) + " |"
    lines = ["# Generalisation study: error against the amount of training motion", "",
             "Each cell: L1 x 1e-3 of the network, and in brackets its gain over Loop subdivision alone (predictor / "
             "network: above 1, the network helps). Every network was trained for the same number of optimiser "
             "steps; `N seq.` on a dataset of the scene's first N training sequences, `N frames` on the scene's own "
             "dataset within N frames of whole training sequences, the oracle on every frame and the held-out motion "
             "too (its held-out error is what the network can capture of that motion at all). Test = a share of "
             "the trained sequences' frames. Networks: "
             + ", ".join(f"`{v}` {parameters[v]:,} parameters" for v in variants) + ".", "",
             f"![held-out and test L1 against the frames trained on]({os.path.relpath(plot, path.parent)})", ""]
    for split, title in (("held_out", "Held-out motion"), ("test", "Test frames of the trained motions")):
        network, predictor = l1["network"][split] / PAPER_UNIT, l1["predictor"][split] / PAPER_UNIT
        lines += [f"## {title}", "", header, "|---" * (len(labels) + 1) + "|"]
        for k, variant in enumerate(variants):
            cells = [f"{network[k, j]:.3f} ({predictor[k, j] / network[k, j]:.2f}x)" for j in range(len(labels))]
            lines.append(f"| `{variant}` | " + " | ".join(cells) + " |")
        lines += ["| Loop subdivision alone | " + " | ".join(f"{v:.3f}" for v in predictor[0]) + " |", ""]
    with atomic_write(path) as f:
        f.write(("\n".join(lines) + "\n").encode())


def _label_words(label: str) -> str:
    """A point's label in a column header: `4 seq.`, `≤ 10,000 frames`, `oracle`."""
    if label == "oracle":
        return label
    return f"{label[1:]} seq." if label[0] == "n" else f"≤ {int(label[1:]):,} frames"
