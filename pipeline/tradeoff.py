"""Stage `tradeoff`: the speed-accuracy trade of a scene's learned path, as a table, a Pareto plot and a report.

    python -m pipeline.tradeoff SUBDIV.h5 TRADEOFF.h5 PLOT.png REPORT.md --sim-high SIM_HIGH.h5 [...]
        --point SUBSTEPS SIM_LOW.h5 [SIM_LOW.h5 ...] [--point ...] --eval SUBSTEPS EVAL.h5 [--eval ...]
        [--settings SETTINGS.json] [--device cpu] [--threads N] [--timing-frames 30] [--iterations N]

Each point is a low-res solver budget: the scene's sequences re-simulated at low resolution with SUBSTEPS
substeps (SIM_LOW.h5: the runs of that budget whose solver timing counts, one solver world each) and fed,
through Loop subdivision, to networks trained on the scene's own budget (the scene's, and smaller ones); each EVAL.h5 is the evaluate stage's measure of one network on that
budget's inputs (errors against the sequences' high-res runs, the network timed on the deployment path, and the
network's conv and width as recorded). The input a cheaper solver makes lies outside the training data (paper
Fig. 14): the errors say what that shift costs. Each budget gives a row per network and one for Loop
subdivision alone (network "none"). Times are ms per frame of one sequence: the low-res solve (the solver's own
timing, median over every frame of the budget's runs), Loop subdivision (timed here, the deployment's gather
and weighted sum, after warm-up, a replayed CUDA graph on a GPU), the network (eval.h5); the high-res solve is
the median of the SIM_HIGH.h5 runs' solve_ms per sequence (a batch's total divided by its sequences: on a GPU,
where a batch costs about one sequence, that understates the high-res cost, so the speedup is a lower bound).
speedup = ms_sim_high / ms_total (paper Table 3's "X" columns).
"""
from __future__ import annotations

import argparse
import os
import re
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp
import torch

from model.inference import CapturedCall, padded_stencil
from pipeline import cli
from pipeline.artifacts.evaluation import read_errors
from pipeline.artifacts.h5 import atomic_write
from pipeline.artifacts.simulation import read_trajectory
from pipeline.artifacts.subdiv import read_subdivision
from pipeline.artifacts.tradeoff import (FLOAT_COLUMNS, INT_COLUMNS, Tradeoff, read_network_timing, read_solve_ms,
                                         write_tradeoff)
from pipeline.errors import PipelineError
from pipeline.torch_setup import configure_torch
from viz.tradeoff_plot import tradeoff_plot

PAPER_UNIT = 1e-3
WARMUP_RUNS = 3
LOOP_ONLY = "none"     # the `network` of a row without a network: Loop subdivision alone


def pareto_front(ms: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Which points no other point beats: none is at most as slow and at most as wrong, and better in one."""
    ms, error = np.asarray(ms, dtype=np.float64), np.asarray(error, dtype=np.float64)
    dominated = ((ms[None, :] <= ms[:, None]) & (error[None, :] <= error[:, None])
                 & ((ms[None, :] < ms[:, None]) | (error[None, :] < error[:, None])))
    return ~dominated.any(axis=1)


def time_subdivision(S: sp.spmatrix, low: np.ndarray, device: torch.device, frames: int) -> np.ndarray:
    """ms of Loop subdivision S x_low per frame (`low`: (F, V_low, 3) frames, cycled) as the deployment runs it
    (model.inference's padded stencil: a gather and a weighted sum; one replayed CUDA graph on a GPU), each after
    WARMUP_RUNS untimed runs, synchronised on CUDA."""
    columns, weights = (torch.as_tensor(a, device=device) for a in padded_stencil(S))
    weights = weights[..., None]
    inputs = torch.as_tensor(low, dtype=torch.float32, device=device)[:, None]     # (F, 1, V_low, 3)

    def subdivide(x: torch.Tensor) -> torch.Tensor:
        return (x[:, columns] * weights).sum(dim=2)

    run = CapturedCall(subdivide, inputs[0]) if device.type == "cuda" else subdivide
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    times = []
    with torch.inference_mode():
        for i in range(-WARMUP_RUNS, max(frames, 1)):
            x = inputs[max(i, 0) % len(inputs)]
            sync()
            start = time.perf_counter()
            run(x)
            sync()
            if i >= 0:
                times.append((time.perf_counter() - start) * 1e3)
    return np.asarray(times)


def per_sequence_ms(paths: Sequence[str]) -> tuple[float, int]:
    """Median ms per frame of one sequence over every solved frame of the runs, and the largest batch among
    them (a batch's ms divided by its sequences)."""
    runs = [read_solve_ms(path) for path in paths]
    return float(np.median(np.concatenate([ms / batch for ms, batch in runs]))), max(batch for _, batch in runs)


def _budget(text: str, flag: str) -> int:
    if not re.fullmatch(r"[1-9][0-9]*", text):
        raise PipelineError(f"{flag} {text}: SUBSTEPS must be a positive integer")
    return int(text)


def parse_grid(points: list[list[str]], evals: list[list[str]]) -> list[tuple[int, list[str], list[str]]]:
    """(substeps, its SIM_LOW.h5 runs, its EVAL.h5 files in the order given) per budget, in budget order."""
    runs: dict[int, list[str]] = {}
    for point in points:
        n = _budget(point[0], "--point")
        if len(point) < 2 or n in runs:
            raise PipelineError(f"--point {' '.join(point)}: give each SUBSTEPS once, with at least one SIM_LOW.h5")
        runs[n] = point[1:]
    evaluations: dict[int, list[str]] = {n: [] for n in runs}
    for n_text, path in evals:
        n = _budget(n_text, "--eval")
        if n not in runs:
            raise PipelineError(f"--eval {n_text} {path}: no --point {n_text} gives that budget's runs")
        evaluations[n].append(path)
    missing = [n for n, paths in evaluations.items() if not paths]
    if missing:
        raise PipelineError(f"--point {missing[0]}: no --eval of that budget")
    return [(n, runs[n], evaluations[n]) for n in sorted(runs)]


def flags_from_settings(settings: dict) -> dict[str, Any]:
    return {"device": settings["device"], "timing_frames": settings["evaluation"]["timing_frames"],
            "iterations": settings["solver"]["iterations"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tradeoff", description=__doc__.splitlines()[0])
    parser.add_argument("subdiv", help="the scene's subdiv.h5 (S, for timing Loop subdivision)")
    parser.add_argument("table", help="tradeoff.h5 to write")
    parser.add_argument("plot", help="pareto.png to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--sim-high", nargs="+", required=True, metavar="SIM_HIGH.h5",
                        help="the high-res runs of the sequences (their solve time is the reference)")
    parser.add_argument("--point", nargs="+", action="append", required=True, metavar="SUBSTEPS SIM_LOW.h5",
                        help="a low-res budget and its runs")
    parser.add_argument("--eval", nargs=2, action="append", required=True, metavar=("SUBSTEPS", "EVAL.h5"),
                        help="a network evaluated on that budget's inputs (repeatable)")
    parser.add_argument("--device", default="cpu", help="torch device timing Loop subdivision")
    parser.add_argument("--timing-frames", type=int, default=30)
    parser.add_argument("--iterations", type=int, default=0, help="the low-res solver's iterations (a column)")
    cli.add_threads(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    grid = parse_grid(args.point, args.eval)
    cli.refuse_aliases({"TRADEOFF.h5": args.table, "PLOT.png": args.plot, "REPORT.md": args.report},
                       {"SUBDIV.h5": args.subdiv, **{f"SIM_HIGH.h5 {i}": p for i, p in enumerate(args.sim_high)},
                        **{f"budget {n} file {i}": p for n, lows, evals in grid
                           for i, p in enumerate([*lows, *evals])}})
    device = configure_torch(args.device, 0, args.threads)
    S = read_subdivision(args.subdiv).S
    ms_high, high_batch = per_sequence_ms(args.sim_high)
    rows: dict[str, list] = {name: [] for name in (*INT_COLUMNS, *FLOAT_COLUMNS, "network")}
    where = None
    for substeps, low_paths, eval_paths in grid:
        ms_low, _ = per_sequence_ms(low_paths)
        low = read_trajectory(low_paths[0]).positions
        if low.shape[1] != S.shape[1]:
            raise PipelineError(f"{low_paths[0]}: {low.shape[1]} vertices, but S of {args.subdiv} takes {S.shape[1]}")
        ms_subdiv = float(np.median(time_subdivision(S, low[1:], device, args.timing_frames)))
        measured = []
        for path in eval_paths:
            timing = read_network_timing(path)
            where = timing.device
            measured.append((read_errors(path)["network"], timing.name, float(np.median(timing.inference_ms)),
                             timing.params))
        # Loop subdivision alone: the predictor of the budget's dataset, the same in each of its evaluations.
        measured.append((read_errors(eval_paths[0])["predictor"], LOOP_ONLY, 0.0, 0))
        for split, name, ms_net, count in measured:
            total = ms_low + ms_subdiv + ms_net
            values = {"substeps": substeps, "iterations": args.iterations, "params": count, "network": name,
                      "l1_test": split["test"]["l1"], "l2_test": split["test"]["l2"],
                      "l1_heldout": split.get("held_out", {}).get("l1", np.nan),
                      "l2_heldout": split.get("held_out", {}).get("l2", np.nan),
                      "ms_sim_low": ms_low, "ms_subdiv": ms_subdiv, "ms_net": ms_net, "ms_total": total,
                      "ms_sim_high": ms_high, "speedup": ms_high / total}
            for key, value in values.items():
                rows[key].append(value)
    table = Tradeoff(rows.pop("network"), {k: np.asarray(v) for k, v in rows.items()}, where,
                     torch.get_num_threads(), high_batch)
    write_tradeoff(args.table, vars(args), table)
    with atomic_write(args.plot) as f:
        errors = _plotted_errors(table)
        f.write(tradeoff_plot(_labels(table), table.columns["ms_total"], errors,
                              {split: pareto_front(table.columns["ms_total"], e) for split, e in errors.items()}))
    _write_report(Path(args.report), Path(args.plot), table, os.getloadavg())


def _labels(table: Tradeoff) -> list[str]:
    return [f"{n} sub, {'Loop only' if net == LOOP_ONLY else net}"
            for n, net in zip(table.columns["substeps"], table.network)]


def _plotted_errors(table: Tradeoff) -> dict[str, np.ndarray]:
    """L1 x 1e-3 per split the scene has (held-out only where it has a held-out motion)."""
    errors = {"test": table.columns["l1_test"] / PAPER_UNIT}
    if np.all(np.isfinite(table.columns["l1_heldout"])):
        errors["held-out"] = table.columns["l1_heldout"] / PAPER_UNIT
    return errors


def _write_report(path: Path, plot: Path, table: Tradeoff, load: tuple[float, float, float]) -> None:
    c = table.columns
    front = pareto_front(c["ms_total"], c["l1_heldout"] if "held-out" in _plotted_errors(table) else c["l1_test"])
    header = ("| substeps x iterations | network | params | test L1 | test L2 | held-out L1 | held-out L2 | "
              "low-res sim | Loop subdiv. | network | learned path | high-res sim | speedup |")
    lines = ["# Speed-accuracy trade: low-res solver budget and network size", "",
             f"Device: {table.device}; torch threads: {table.threads}; load average when tabulated: "
             f"{load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1 / 5 / 15 min).", "",
             "The networks, trained on the scene's own low-res budget, are fed the low-res runs made with fewer "
             "substeps (the input shift of paper Fig. 14); Loop subdivision alone is the floor. Errors x 1e-3 "
             "scene units against the high-res runs (as the scene's report); times in ms per frame of one "
             "sequence: low-res solve (the solver's own timing), Loop subdivision and network (the deployment "
             "path, median after warm-up), their sum (the learned path), and the high-res solve"
             + (f" (a batch of {table.sim_high_batch} sequences' ms divided by {table.sim_high_batch}: a lower "
                f"bound of one sequence's on a GPU)" if table.sim_high_batch > 1 else "")
             + ". speedup = high-res sim / learned path. **Bold**: on the Pareto front (no row both faster and "
             "more accurate).", "", f"![error against ms per frame]({os.path.relpath(plot, path.parent)})", "",
             header, "|---" * (header.count("|") - 1) + "|"]
    for i, name in enumerate(table.network):
        mark = "**" if front[i] else ""
        cells = [f"{mark}{c['substeps'][i]} x {c['iterations'][i]}{mark}",
                 "Loop subdivision alone" if name == LOOP_ONLY else name, f"{c['params'][i]:,}",
                 *[f"{c[k][i] / PAPER_UNIT:.3f}" if np.isfinite(c[k][i]) else "-"
                   for k in ("l1_test", "l2_test", "l1_heldout", "l2_heldout")],
                 *[f"{c[k][i]:.3g}" for k in ("ms_sim_low", "ms_subdiv", "ms_net", "ms_total", "ms_sim_high")],
                 f"{c['speedup'][i]:.1f}x"]
        lines.append("| " + " | ".join(cells) + " |")
    with atomic_write(path) as f:
        f.write(("\n".join(lines) + "\n").encode())


if __name__ == "__main__":
    cli.run(main)
