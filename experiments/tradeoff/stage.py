"""Stage `tradeoff`: the speed-accuracy trade of every way to a scene's high-res cloth: a table, a plot, a report.

    python -m experiments.tradeoff SUBDIV.h5 TRADEOFF.h5 PLOT.png REPORT.md --sim-high SIM_HIGH.h5 [...]
        --dataset DATASET.h5 --operators OPERATORS.h5 --settings SETTINGS.json
        --solve-timing SCENE.h5 SIM_LOW.h5 [--settled SETTLE_LOW.h5 SETTLE_HIGH.h5]
        --point BUDGET SIM_LOW.h5 [--point ...] --eval BUDGET EVAL.h5 MODEL.pt [--eval ...]
        [--matched BUDGET EVAL.h5 MODEL.pt ...] [--high-res SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5 [...] ...]
        [--high-res-timing SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5 [...] ...] [--scene-report REPORT.md]
        [--device cpu] [--threads N] [--timing-frames 30] [--substeps N] [--iterations N] [--harmonic-every substep]

Every row is a way to get the high-res cloth, scored against the scene's high-res runs (--sim-high, one per
sequence in the dataset's order: the ground truth) and timed against the high-res solver free (below).

* Learned path, per low-res budget (--point BUDGET: N substeps at the scene's --iterations, or NxI substeps x
  iterations): the scene's sequences re-simulated at low resolution with that solver budget (SIM_LOW.h5: a run of
  it, whose frames time Loop subdivision), Loop-subdivided and fed to
  networks; each --eval EVAL.h5 MODEL.pt is the evaluate stage's measure of a network trained on the scene's own
  budget (--substeps) fed that budget's inputs (errors against the high-res runs, its conv and width as recorded)
  and the network itself. The input a cheaper solver makes lies outside that training data (paper Fig. 14): the
  errors say what the shift costs. A --matched EVAL.h5 MODEL.pt is a network trained on the budget's own inputs
  (the scene's recipe, or it at another width): whether matching the training input to the deployed budget
  removes the shift. Each budget also gives a row for Loop subdivision alone (network "none").
* High-res runs (--high-res): the high-res solver itself at SUBSTEPS x ITERATIONS with the harmonic projection
  every SCHEDULE (iteration or substep), held to the scene's low-res runs, one SIM_HIGH.h5 per sequence in the
  order of --sim-high; scored against the scene's high-res runs on the dataset's test and held-out frames
  (--dataset: the scene's dataset.h5, which says where each frame comes from and its frame of reference), as the
  evaluate stage scores a network: L1 (eq. 4), L2 (eq. 5).

Times are ms per frame of one sequence, and both sides of a learned row's speedup are measured in this job, one
after another on the device: the reference, the high-res solver at the scene's budget with body and self collision,
free (not held to a low-res run: the paper's reference, what the learned path replaces), and each budget's low-res
solve, each the median over every frame of the --solve-timing sequence stepped alone (SCENE.h5 and its low-res run
at the scene's budget, where the high-res run starts; --settled: the scene's settle runs a motion library's window
starts from; experiments.tradeoff.solve_timing; a low-res solve with each frame kernel where the sweeps and `auto`
differ on the device, the faster kept and named beside the other's ms); Loop subdivision (the deployment's gather
and weighted sum, after warm-up, a replayed CUDA graph on a GPU); the network (each MODEL.pt once, one after
another, on the deployment path as the evaluate stage times it, on test frames of --dataset: fp32 and, on CUDA, the
fused bf16 network with its error against fp32; the evaluations ran side by side with whatever shared the device, so
their own ms are not compared). A high-res row's own solve is the median of the solve_ms per sequence of its runs
(--high-res-timing SUBSTEPS ITERATIONS SCHEDULE: one sequence alone, as a sharded scene's workflow gives; else the
runs themselves, a batch's total divided by its sequences). speedup = ms_sim_high / ms_total (paper Table 3's "X"
columns); speedup_fused the same with the fused network's ms.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp
import torch

from experiments.tradeoff.artifact import (COLUMNS, HIGH_RES, LEARNED, LOOP, NO_NETWORK, Reference, Tradeoff,
                                          write_tradeoff)
from experiments.tradeoff.report import pareto_plot, write_report
from experiments.tradeoff.solve_timing import LowResMs, TimedSequence, free_high_res_ms, low_res_ms
from geometry.rigid import apply_rigid_inverse
from model.cuda_graph import CapturedCall
from model.inference import padded_stencil, stencil_product
from pipeline.artifacts.dataset import load_dataset
from pipeline.artifacts.dataset import FrameOrigins, read_frame_origins
from pipeline.artifacts.evaluation import read_errors, read_network_timing
from pipeline.artifacts.model import load_model
from pipeline.artifacts.simulation import read_solve_ms, read_trajectory
from pipeline.artifacts.subdiv import read_subdivision
from pipeline.core import cli
from pipeline.core.config import read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write
from pipeline.core.torch_setup import configure_torch, timing_device
from pipeline.tasks import frames_of
from pipeline.tasks.timing import WARMUP_RUNS, pick_frames, time_inference

SCHEDULES = ("iteration", "substep")


def time_subdivision(S: sp.spmatrix, low: np.ndarray, device: torch.device, frames: int) -> np.ndarray:
    """ms of Loop subdivision S x_low per frame (`low`: (F, V_low, 3) frames, cycled) as the deployment runs it
    (model.inference.stencil_product of its padded stencil; on a GPU the fused path's Triton kernel in one
    replayed CUDA graph), each after WARMUP_RUNS untimed runs, synchronised on CUDA."""
    columns, weights = (torch.as_tensor(a, device=device) for a in padded_stencil(S))
    inputs = torch.as_tensor(low, dtype=torch.float32, device=device)[:, None]     # (F, 1, V_low, 3)

    def subdivide(x: torch.Tensor) -> torch.Tensor:
        return stencil_product(columns, weights, x, kernel=device.type == "cuda")

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


def high_res_errors(origins: FrameOrigins, reference: Sequence[str], runs: Sequence[str]) -> dict[str, dict]:
    """L1 (eq. 4: mean |x - x_ref| over coordinates) and L2 (eq. 5: root of the mean squared distance) of the
    high-res `runs` against the `reference` runs (one per sequence of `origins`, in its order) over the frames of
    each split taken together, in the dataset's frame of reference (L1 is not rotation invariant): the numbers
    the evaluate stage reports for a network."""
    if not len(reference) == len(runs) == len(origins.names):
        raise PipelineError(f"{runs[0]}: {len(runs)} high-res runs and {len(reference)} reference runs for a "
                            f"dataset of {len(origins.names)} sequences ({', '.join(origins.names)})")
    sums = {split: np.zeros(2) for split in origins.splits}        # sum over frames of L1 and of L2 squared
    for k, (ref_path, run_path) in enumerate(zip(reference, runs)):
        rows = {split: ids[origins.sequence[ids] == k] for split, ids in origins.splits.items()}
        if not any(len(r) for r in rows.values()):
            continue
        ref, run = read_trajectory(ref_path).positions, read_trajectory(run_path).positions
        if ref.shape != run.shape:
            raise PipelineError(f"{run_path}: positions {run.shape}, but the reference {ref_path} has {ref.shape}")
        for split, r in rows.items():
            frames = origins.sequence_frame[r]
            if len(frames) and frames.max() >= len(ref):
                raise PipelineError(f"{ref_path}: {len(ref)} frames, but the dataset takes frame {frames.max()} "
                                    f"of sequence '{origins.names[k]}' from it")
            x, x_ref = run[frames], ref[frames]
            if origins.torso is not None:
                to_torso = origins.torso[r][:, None]
                x, x_ref = apply_rigid_inverse(to_torso, x), apply_rigid_inverse(to_torso, x_ref)
            difference = x - x_ref
            sums[split] += [np.abs(difference).mean(axis=(1, 2)).sum(),
                            np.square(difference).sum(axis=2).mean(axis=1).sum()]
    counts = {split: len(ids) for split, ids in origins.splits.items()}
    return {split: {"l1": l1 / counts[split], "l2": float(np.sqrt(l2sq / counts[split]))}
            for split, (l1, l2sq) in sums.items()}


@dataclasses.dataclass(frozen=True)
class Network:
    """A network fed a budget's inputs: its evaluation there (errors) and the model itself (timed here)."""
    eval: str
    model: str


@dataclasses.dataclass(frozen=True)
class Budget:
    """A low-res budget of the grid: its solver budget, its runs (the first's frames time Loop subdivision) and the
    networks fed its inputs."""
    substeps: int
    iterations: int
    low_runs: list[str]
    evals: list[Network]        # networks trained on the scene's budget, in the order given
    matched: list[Network]      # networks trained on this budget's own inputs, in the order given


@dataclasses.dataclass(frozen=True)
class HighResRun:
    """A high-res run of another budget or schedule than the scene's: one SIM_HIGH.h5 per sequence (its errors)
    and the runs whose solve_ms is its time (the runs themselves, or one sequence alone)."""
    substeps: int
    iterations: int
    harmonic_every: str
    runs: list[str]
    timed: list[str]


def _positive(text: str, flag: str, what: str = "SUBSTEPS") -> int:
    if not re.fullmatch(r"[1-9][0-9]*", text):
        raise PipelineError(f"{flag} {text}: {what} must be a positive integer")
    return int(text)


def _budget(text: str, flag: str, iterations: int) -> tuple[int, int]:
    """(substeps, iterations) of a budget's name: N (at the scene's `iterations`) or NxI."""
    if not re.fullmatch(r"[1-9][0-9]*(x[1-9][0-9]*)?", text):
        raise PipelineError(f"{flag} {text}: BUDGET must be N (substeps at the scene's iterations) or NxI "
                            f"(substeps x iterations), positive integers")
    substeps, _, own = text.partition("x")
    return int(substeps), int(own) if own else iterations


def parse_grid(points: list[list[str]], evals: list[list[str]], matched: list[list[str]],
               iterations: int) -> list[Budget]:
    """The budgets in budget order (substeps, then iterations; a bare N at the scene's `iterations`), each with
    its runs, its evaluations and its matched networks' evaluations in the order given."""
    runs: dict[tuple[int, int], list[str]] = {}
    names: dict[tuple[int, int], str] = {}
    for point in points:
        key = _budget(point[0], "--point", iterations)
        if len(point) < 2 or key in runs:
            raise PipelineError(f"--point {' '.join(point)}: give each BUDGET once, with at least one SIM_LOW.h5")
        runs[key], names[key] = point[1:], point[0]
    networks: dict[str, dict[tuple[int, int], list[Network]]] = {
        flag: {key: [] for key in runs} for flag in ("--eval", "--matched")}
    for flag, triples in (("--eval", evals), ("--matched", matched)):
        for text, path, model in triples:
            key = _budget(text, flag, iterations)
            if key not in runs:
                raise PipelineError(f"{flag} {text} {path}: no --point of that budget gives its runs")
            if any(network.eval == path for network in networks["--eval"][key] + networks["--matched"][key]):
                raise PipelineError(f"{flag} {text} {path}: that evaluation is given twice")
            networks[flag][key].append(Network(path, model))
    missing = [key for key, paths in networks["--eval"].items() if not paths]
    if missing:
        raise PipelineError(f"--point {names[missing[0]]}: no --eval of that budget")
    return [Budget(*key, runs[key], networks["--eval"][key], networks["--matched"][key]) for key in sorted(runs)]


def _high_res_key(group: list[str], flag: str) -> tuple[int, int, str]:
    if len(group) < 4:
        raise PipelineError(f"{flag} {' '.join(group)}: give SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5 ...")
    key = (_positive(group[0], flag), _positive(group[1], flag, "ITERATIONS"), group[2])
    if key[2] not in SCHEDULES:
        raise PipelineError(f"{flag} {' '.join(group[:3])}: SCHEDULE must be one of {', '.join(SCHEDULES)}")
    return key


def parse_high_res(groups_: list[list[str]], reference: Reference,
                   timing: Sequence[list[str]] = ()) -> list[HighResRun]:
    """The --high-res runs in the order given, each timed by its --high-res-timing runs if any (else by its own);
    the scene's own budget and schedule is the ground truth, refused."""
    runs: dict[tuple[int, int, str], list[str]] = {}
    for group in groups_:
        key = _high_res_key(group, "--high-res")
        if key == (reference.substeps, reference.iterations, reference.harmonic_every):
            raise PipelineError(f"--high-res {' '.join(group[:3])}: that is the scene's own high-res run, the "
                                f"ground truth (--sim-high)")
        if key in runs:
            raise PipelineError(f"--high-res {' '.join(group[:3])}: given twice")
        runs[key] = group[3:]
    timed: dict[tuple[int, int, str], list[str]] = {}
    for group in timing:
        key = _high_res_key(group, "--high-res-timing")
        if key not in runs:
            raise PipelineError(f"--high-res-timing {' '.join(group[:3])}: no --high-res run of that budget and "
                                f"schedule")
        if key in timed:
            raise PipelineError(f"--high-res-timing {' '.join(group[:3])}: given twice")
        timed[key] = group[3:]
    return [HighResRun(*key, paths, timed.get(key, paths)) for key, paths in runs.items()]


def networks_of(budget: Budget) -> list[Network]:
    return [*budget.evals, *budget.matched]


@dataclasses.dataclass(frozen=True)
class NetworkMs:
    """A model's median ms per frame on the fp32 deployment path and, where it was timed (CUDA), the fused bf16
    network's and its error against the fp32 path (pipeline.tasks.timing); NaN: not timed."""
    fp32: float
    fused: float = np.nan
    fused_error: float = np.nan


NOT_TIMED = NetworkMs(0.0)      # a row without a network: nothing to time, no fused network
NO_LOW_RES = LowResMs(0.0, "")  # a row without a low-res solve (high_res)


def make_row(method: str, network: str, substeps: int, iterations: int, trained: tuple[int, int], params: int,
             errors: dict[str, dict[str, float]], sim_low: LowResMs, ms_subdiv: float, ms_net: NetworkMs,
             ms_sim_high: float, harmonic_every: str = "", ms_sim_high_run: float = 0.0) -> dict[str, Any]:
    """One row of tradeoff.h5 (COLUMNS) from a method's errors (split -> l1, l2; no held_out: NaN) and times (the
    low-res solve's with its frame kernel in sim_low, a high-res row's own solve in ms_sim_high_run, the
    reference's in ms_sim_high; `trained`: the (substeps, iterations) of the network's training inputs, (0, 0)
    without a network): ms_total is the sum of the row's parts, speedup the reference high-res ms over it; the
    same with the fused bf16 network in place of the fp32 one (NaN where it was not timed)."""
    total = sim_low.ms + ms_subdiv + ms_net.fp32 + ms_sim_high_run
    total_fused = sim_low.ms + ms_subdiv + ms_net.fused + ms_sim_high_run
    held_out = errors.get("held_out", {})
    return {"method": method, "network": network, "harmonic_every": harmonic_every,
            "sim_low_kernel": sim_low.frame_kernel, "substeps": substeps,
            "iterations": iterations, "trained_substeps": trained[0], "trained_iterations": trained[1],
            "params": params,
            "l1_test": errors["test"]["l1"], "l2_test": errors["test"]["l2"],
            "l1_heldout": held_out.get("l1", np.nan), "l2_heldout": held_out.get("l2", np.nan),
            "ms_sim_low": sim_low.ms, "ms_sim_low_other": sim_low.other_ms, "ms_subdiv": ms_subdiv,
            "ms_net": ms_net.fp32, "ms_sim_high_run": ms_sim_high_run,
            "ms_total": total, "ms_sim_high": ms_sim_high, "speedup": ms_sim_high / total,
            "ms_net_fused": ms_net.fused, "fused_error": ms_net.fused_error, "ms_total_fused": total_fused,
            "speedup_fused": ms_sim_high / total_fused}


def budget_rows(budget: Budget, reference: Reference, sim_low: LowResMs, ms_subdiv: float, ms_sim_high: float,
                ms_net: Mapping[str, NetworkMs]) -> list[dict[str, Any]]:
    """The rows of a budget: each network fed its inputs (the scene-trained ones, then the matched ones; `ms_net`
    by model path), then Loop subdivision alone (the predictor of the budget's dataset)."""
    rows = []
    trained = ([(network, (reference.substeps, reference.iterations)) for network in budget.evals]
               + [(network, (budget.substeps, budget.iterations)) for network in budget.matched])
    for network, inputs in trained:
        evaluated = read_network_timing(network.eval)
        rows.append(make_row(LEARNED, evaluated.name, budget.substeps, budget.iterations, inputs, evaluated.params,
                             read_errors(network.eval)["network"], sim_low, ms_subdiv, ms_net[network.model],
                             ms_sim_high))
    rows.append(make_row(LOOP, NO_NETWORK, budget.substeps, budget.iterations, (0, 0), 0,
                         read_errors(budget.evals[0].eval)["predictor"], sim_low, ms_subdiv, NOT_TIMED,
                         ms_sim_high))
    return rows


def time_networks(networks: Sequence[Network], dataset: str, operators: str, device: torch.device,
                  frames: int) -> dict[str, NetworkMs]:
    """Median ms per frame of each distinct model on the deployment path (pipeline.tasks.timing: fp32 and, on
    CUDA, the fused bf16 network with its error against fp32), one model after another in this one process, on
    `frames` test frames of the dataset; each model's parameter count checked against its evaluation's (an
    evaluation of another network would pair its errors with these ms)."""
    data = load_dataset(dataset)
    store = frames_of(data, device).store
    ids = torch.as_tensor(pick_frames(data.test, frames), device=device)
    ms = {}
    for network in networks:
        if network.model in ms:
            continue
        model, mesh, state = load_model(network.model, operators, str(device))
        evaluated = read_network_timing(network.eval).params
        if state["parameter_count"] != evaluated:
            raise PipelineError(f"{network.eval}: the evaluation of a network of {evaluated:,} parameters, but "
                                f"{network.model} has {state['parameter_count']:,}: not that model's evaluation")
        times = time_inference(model, mesh, store, ids)
        ms[network.model] = NetworkMs(float(np.median(times))) if times.fused is None else NetworkMs(
            float(np.median(times)), float(np.median(times.fused.ms)), times.fused.error)
        del model
    return ms


def high_res_row(run: HighResRun, origins: FrameOrigins, reference_runs: Sequence[str],
                 ms_sim_high: float) -> dict[str, Any]:
    """A cheaper high-res run as a row: its errors against the reference runs, its solve as the whole time."""
    ms, _ = per_sequence_ms(run.timed)
    return make_row(HIGH_RES, NO_NETWORK, run.substeps, run.iterations, (0, 0), 0,
                    high_res_errors(origins, reference_runs, run.runs), NO_LOW_RES, 0.0, NOT_TIMED, ms_sim_high,
                    run.harmonic_every,
                    ms_sim_high_run=ms)


def table_of(rows: list[dict[str, Any]], device: str, threads: int, reference: Reference) -> Tradeoff:
    return Tradeoff({name: np.asarray([row[name] for row in rows]) for name in COLUMNS}, device, threads, reference)


def flags_from_settings(settings: dict) -> dict[str, Any]:
    return {"device": settings["device"], "timing_frames": settings["evaluation"]["timing_frames"],
            "substeps": settings["solver"]["substeps"], "iterations": settings["solver"]["iterations"],
            "harmonic_every": settings["high_res"]["harmonic_every"]}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.tradeoff", description=__doc__.splitlines()[0])
    parser.add_argument("subdiv", help="the scene's subdiv.h5 (S, for timing Loop subdivision)")
    parser.add_argument("table", help="tradeoff.h5 to write")
    parser.add_argument("plot", help="pareto.png to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--sim-high", nargs="+", required=True, metavar="SIM_HIGH.h5",
                        help="the scene's high-res runs, one per sequence in the dataset's order (the ground "
                             "truth)")
    parser.add_argument("--point", nargs="+", action="append", required=True, metavar="BUDGET SIM_LOW.h5",
                        help="a low-res budget (N substeps at the scene's iterations, or NxI) and its runs (the "
                             "first's frames time Loop subdivision)")
    parser.add_argument("--eval", nargs=3, action="append", required=True,
                        metavar=("BUDGET", "EVAL.h5", "MODEL.pt"),
                        help="a network trained on the scene's budget, evaluated on that budget's inputs")
    parser.add_argument("--matched", nargs=3, action="append", default=[],
                        metavar=("BUDGET", "EVAL.h5", "MODEL.pt"),
                        help="a network trained on that budget's own inputs, evaluated on them")
    parser.add_argument("--high-res", nargs="+", action="append", default=[],
                        metavar="SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5",
                        help="high-res runs of another budget or schedule, one per sequence as --sim-high")
    parser.add_argument("--solve-timing", nargs=2, required=True, metavar=("SCENE.h5", "SIM_LOW.h5"),
                        help="the sequence the solvers are timed on here: its scene file and its low-res run at the "
                             "scene's budget (where the free high-res run starts)")
    parser.add_argument("--settled", nargs=2, metavar=("SETTLE_LOW.h5", "SETTLE_HIGH.h5"),
                        help="the scene's settle runs, where the --solve-timing sequence starts if it is a motion "
                             "library's window")
    parser.add_argument("--high-res-timing", nargs="+", action="append", default=[],
                        metavar="SUBSTEPS ITERATIONS SCHEDULE SIM_HIGH.h5",
                        help="the runs whose solve_ms times that --high-res run (default: its own runs)")
    parser.add_argument("--dataset", required=True, help="the scene's dataset.h5: the frames --high-res runs are "
                                                         "scored on and the networks timed on")
    parser.add_argument("--operators", required=True, help="the scene's operators.h5 (the networks' tables)")
    parser.add_argument("--scene-report", help="the scene's report.md, linked from REPORT.md (default: beside "
                                               "REPORT.md's folder)")
    parser.add_argument("--device", default="cpu", help="where the solvers, Loop subdivision and the networks are "
                                                        "timed (torch's and Warp's name: cpu, cuda, cuda:0)")
    parser.add_argument("--timing-frames", type=int, default=30)
    parser.add_argument("--substeps", type=int, default=8, help="the scene's low-res substeps (the scene-trained "
                                                                "networks' inputs; with --iterations the "
                                                                "reference high-res budget)")
    parser.add_argument("--iterations", type=int, default=75, help="the scene's solver iterations")
    parser.add_argument("--harmonic-every", choices=SCHEDULES, default="substep",
                        help="the scene's high-res harmonic schedule (the reference's)")
    cli.add_threads(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    settings_path = cli.settings_of(argv)
    if settings_path is None:
        parser.error("--settings is required: the solvers timed here are the scene's")
    reference = Reference(args.substeps, args.iterations, args.harmonic_every)
    grid = parse_grid(args.point, args.eval, args.matched, args.iterations)
    high_res = parse_high_res(args.high_res, reference, args.high_res_timing)
    scene_report = Path(args.scene_report or Path(args.report).parent.parent / "report.md")
    cli.refuse_aliases({"TRADEOFF.h5": args.table, "PLOT.png": args.plot, "REPORT.md": args.report},
                       {"SUBDIV.h5": args.subdiv, "DATASET.h5": args.dataset, "OPERATORS.h5": args.operators,
                        **{f"SIM_HIGH.h5 {i}": p for i, p in enumerate(args.sim_high)},
                        **{f"--solve-timing {i}": p
                           for i, p in enumerate([*args.solve_timing, *(args.settled or [])])},
                        **{f"budget {b.substeps}x{b.iterations} file {i}": p for b in grid
                           for i, p in enumerate([*b.low_runs, *(x for n in networks_of(b) for x in (n.eval, n.model))])},
                        **{f"--high-res {h.substeps} {h.iterations} {h.harmonic_every} file {i}": p
                           for h in high_res for i, p in enumerate([*h.runs, *h.timed])}})
    device = configure_torch(args.device, 0, args.threads, whole_gpu=True)  # both sides of a speedup, alone
    where = timing_device(device)
    S = read_subdivision(args.subdiv).S
    settings = read_settings(settings_path)
    timed = TimedSequence(*args.solve_timing, *(args.settled or (None, None)))
    ms_high = free_high_res_ms(settings, args.subdiv, timed, args.device)
    ms_net = time_networks([n for b in grid for n in networks_of(b)], args.dataset, args.operators, device,
                           args.timing_frames)
    rows = []
    for budget in grid:
        sim_low = low_res_ms(settings, (budget.substeps, budget.iterations), timed, args.device)
        low = read_trajectory(budget.low_runs[0]).positions
        if low.shape[1] != S.shape[1]:
            raise PipelineError(f"{budget.low_runs[0]}: {low.shape[1]} vertices, but S of {args.subdiv} takes "
                                f"{S.shape[1]}")
        ms_subdiv = float(np.median(time_subdivision(S, low[1:], device, args.timing_frames)))
        rows += budget_rows(budget, reference, sim_low, ms_subdiv, ms_high, ms_net)
    if high_res:
        origins = read_frame_origins(args.dataset)
        rows += [high_res_row(run, origins, args.sim_high, ms_high) for run in high_res]
    table = table_of(rows, where, torch.get_num_threads(), reference)
    write_tradeoff(args.table, vars(args), table)
    with atomic_write(args.plot) as f:
        f.write(pareto_plot(table, ms_high))
    write_report(Path(args.report), Path(args.plot), scene_report, table, os.getloadavg())

