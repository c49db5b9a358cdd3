"""Stage `pca_summary`: the PCA details-recovery models side by side, how much of the truncation error each
recovers (paper Table 4 "cape PCA 32 / 64", Fig. 10).

    python -m experiments.pca REPORT.md --model K EVAL.h5 [--model K EVAL.h5 ...]

Each EVAL.h5 is the evaluation of the network trained on the K PCA coefficients (results/<scene>/pca/k<K>/); the
table gives per split the PCA reconstruction's L1 and L2 (the truncation error), the network's, and the share of
the truncation error recovered, 1 - network / PCA.
"""
from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Sequence

from pipeline.artifacts.evaluation import read_errors
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write
from viz.html_report import Paragraphs, Section, Table
from viz.markdown_report import report_markdown

PAPER_UNIT = 1e-3
SPLIT_NAMES = {"train": "train", "test": "test", "held_out": "held-out"}


def summary_rows(models: list[tuple[int, dict]]) -> tuple[list[str], list[list[str]]]:
    """Header and rows (one per component count and split) from (K, read_errors(...)) pairs."""
    header = ["components", "split", "PCA L1", "network L1", "recovered (L1)", "PCA L2", "network L2",
              "recovered (L2)"]
    rows = []
    for k, errors in sorted(models, key=lambda model: model[0]):
        for split in (s for s in SPLIT_NAMES if s in errors["network"]):
            cells = [str(k), SPLIT_NAMES[split]]
            for term in ("l1", "l2"):
                pca, network = errors["predictor"][split][term], errors["network"][split][term]
                cells += [f"{pca / PAPER_UNIT:.3f}", f"{network / PAPER_UNIT:.3f}",
                          f"{1.0 - network / max(pca, 1e-30):.0%}"]
            rows.append(cells)
    return header, rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.pca", description=__doc__.splitlines()[0])
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--model", nargs=2, action="append", required=True, metavar=("K", "EVAL.h5"))
    args = parser.parse_args(argv)
    cli.refuse_aliases({"REPORT.md": args.report}, {f"EVAL.h5 {i}": p for i, (_, p) in enumerate(args.model)})
    if any(not re.fullmatch(r"[0-9]+", k) or int(k) < 1 for k, _ in args.model):
        raise PipelineError("--model K EVAL.h5: K must be a positive integer")
    header, rows = summary_rows([(int(k), read_errors(path)) for k, path in args.model])
    report = Path(args.report)
    links = ", ".join(f"[{k} components]({os.path.relpath(Path(path).parent / 'report.md', report.parent)})"
                      for k, path in sorted(args.model, key=lambda model: int(model[0])))
    sections = [Section("Truncation error recovered (x 1e-3 scene units)", [Table(header, rows), Paragraphs(
        "PCA = the reconstruction from the first K principal components of the high-res run's training frames "
        "(the predictor, the network's input being its K coefficients); network = that reconstruction plus the "
        "decoder's displacement; recovered = 1 - network / PCA, the share of the truncation error the network "
        f"adds back. Each model's own report: {links}.")])]
    with atomic_write(report) as f:
        f.write(report_markdown("PCA details recovery", sections, str).encode())

