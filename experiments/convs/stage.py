"""Stage `convs`: the paper's operator comparison (RC, EC, SP, SPD side by side) from the evaluations of its runs.

    python -m experiments.convs CONVS.h5 CHART.png REPORT.md REPORT.html [--run TASK SEED EVAL.h5 TRAIN.h5 ...]
        [--part EARLIER_CONVS.h5 ...] [--scene-report REPORT.md]

Each run is a network of task TASK (upsampling, or pose: the pose-to-cloth decoder) trained with seed SEED
(TRAIN.h5, the train stage's log: its flags and time) and evaluated (EVAL.h5, the evaluate stage's: its errors per
split, inference times, parameter count, and the network's architecture, convolution and width as model.pt
recorded them). The runs must fill a grid: every architecture and filter length of a task with every operator,
each with the same seeds, every run of a task trained on the same data with the same recipe (RECIPE: only the
architecture, convolution, width and seed may differ) and scored on the same frames (their predictor errors
agree); anything else is refused, since a table of unlike runs would compare unlike things. convs.h5 gets one row
per run; the report the paper's layout (a row per task, architecture and length, a column per operator, the
lowest in bold), a bar chart, which operator wins how often and whether by more than the seeds' spread
(workflow/rules/convs.smk makes the runs).

A grid may be run in parts (some seeds on one machine or day, the others elsewhere): each `--part` is the convs.h5
of such a part, whose rows join the table as if their runs were given, held to the same checks (its rows carry
their errors; its config the recipe each task was trained with).
"""
from __future__ import annotations

import argparse
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from experiments.convs.artifact import COLUMNS, KINDS, TERMS, Convs, read_convs, write_convs
from experiments.convs.grid import POSE, UPSAMPLING
from experiments.convs.report import PAPER_UNIT, TASK_WORDS, rows, sections
from model.architecture import ArchitectureError, parse_conv
from pipeline.artifacts.evaluation import read_errors, read_network_timing
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write, config_of, open_artifact
from viz.convs_plot import convs_plot
from viz.html_report import report_html
from viz.markdown_report import report_markdown

TASK_LETTERS = {UPSAMPLING: "D", POSE: "U"}      # an encoder-decoder, a decoder
EVAL_SPLITS = {"train": "train", "test": "test", "heldout": "held_out"}
# pipeline.train's flags that make a task's recipe: every run of a task must agree on them.
RECIPE = ("dataset", "epochs", "batch_size", "lr", "lr_schedule", "loss_l1", "loss_l2", "loss_normal", "pool",
          "inputs", "input_frame", "output_frame", "frame_tangent", "input_noise", "sample_share", "sample_block",
          "train_on", "train_frames", "cuda_graph", "tf32", "deterministic")


def read_training(seed: str, path: str, conv: str) -> tuple[dict, float]:
    """A run's recipe (RECIPE's flags of its train.h5) and its training seconds, checked against the seed and
    convolution the run claims."""
    with open_artifact(path) as f:
        config, seconds = config_of(f), f.attrs.get("wall_seconds")
    missing = [key for key in RECIPE if key not in config]
    if missing:
        raise PipelineError(f"{path}: its config has no '{missing[0]}': not a train.h5 of pipeline.train")
    if config.get("seed") != int(seed) or config.get("conv") != conv:
        raise PipelineError(f"{path}: trained with seed {config.get('seed')} and conv {config.get('conv')}, not "
                            f"the run's seed {seed} and {conv}: not this run's train.h5")
    if not isinstance(seconds, (float, int, np.floating, np.integer)) or not 0 <= seconds < np.inf:
        raise PipelineError(f"{path}: attribute 'wall_seconds' missing or not a time: not a train.h5 of "
                            f"pipeline.train")
    return {key: config[key] for key in RECIPE}, float(seconds)


def read_run(task: str, seed: str, path: str, train_log: str) -> tuple[dict, dict]:
    """One row of convs.h5 from a run's eval.h5 and train.h5 (COLUMNS), and the run's recipe."""
    if task not in TASK_LETTERS or not re.fullmatch(r"[0-9]+", seed):
        raise PipelineError(f"--run {task} {seed} {path}: TASK must be {' or '.join(TASK_LETTERS)} and SEED a "
                            f"whole number")
    with open_artifact(path) as f:
        spec = config_of(f).get("model_spec", {})
    try:
        arch, (kind, length), width = str(spec["arch"]), parse_conv(str(spec["conv"])), float(spec["width"])
    except (KeyError, TypeError, ValueError, ArchitectureError):
        raise PipelineError(f"{path}: no model_spec with arch, conv and width: not an eval.h5 of pipeline.evaluate") \
            from None
    if arch.strip()[:1] != TASK_LETTERS[task]:
        raise PipelineError(f"{path}: a network of '{arch}', not of task {task} ({TASK_LETTERS[task]} tokens)")
    errors, timing = read_errors(path), read_network_timing(path)
    recipe, seconds = read_training(seed, train_log, f"{kind}{length}")
    row = {"task": task, "kind": kind, "arch": " ".join(arch.split()), "length": length, "seed": int(seed),
           "params": timing.params, "width": width, "ms_inference": float(np.median(timing.inference_ms)),
           "train_seconds": seconds, "device": timing.device}
    for split, name in EVAL_SPLITS.items():
        for term in TERMS:
            for who, prefix in (("network", ""), ("predictor", "loop_")):
                row[f"{prefix}{term}_{split}"] = errors[who][name][term] if name in errors[who] else np.nan
    if any(np.isnan(row[f"{term}_{split}"]) for split in ("train", "test") for term in TERMS):
        raise PipelineError(f"{path}: no train and test errors: not an eval.h5 of pipeline.evaluate")
    return row, recipe


def read_part(path: str) -> list[tuple[dict, dict, tuple[str, str, str, str]]]:
    """The rows of an earlier convs.h5, each with its task's recipe and, where an error names the row's files,
    the part's path."""
    table = read_convs(path)
    recipes, tasks = table.recipes, set(table.columns["task"].tolist())
    if not tasks <= set(recipes) or any(
            not isinstance(recipes[task], dict) or set(RECIPE) - set(recipes[task]) for task in tasks):
        raise PipelineError(f"{path}: its config has no recipe of each task's runs: not a convs.h5 of this stage "
                            f"(or one from before parts could be joined)")
    parts = []
    for k in range(len(table)):
        row = {name: table.columns[name][k].item() for name in COLUMNS}
        row["device"] = table.device
        parts.append((row, {key: recipes[row["task"]][key] for key in RECIPE}, (row["task"], "", path, path)))
    return parts


def gather(runs: list[tuple[str, str, str, str]], parts: Sequence[str] = ()) -> tuple[Convs, dict[str, dict]]:
    """The table from (task, seed, eval.h5, train.h5) per run, in the order given, then the rows of each earlier
    convs.h5 of `parts`, and each task's recipe; one error unless they fill a grid."""
    read = [(*read_run(*run), run) for run in runs] + [entry for part in parts for entry in read_part(part)]
    if not read:
        raise PipelineError("no runs: give --run or --part")
    keys = [(r["task"], r["arch"], r["length"], r["kind"], r["seed"]) for r, _, _ in read]
    for k, key in enumerate(keys):
        if key in keys[:k]:
            raise PipelineError(f"{read[k][2][2]}: the same run as {read[keys.index(key)][2][2]} (task {key[0]}, "
                                f"'{key[1]}', {key[3]}{key[2]}, seed {key[4]})")
    kinds = {r["kind"] for r, _, _ in read}
    recipes = {}
    for task in dict.fromkeys(r["task"] for r, _, _ in read):
        mine = [entry for entry in read if entry[0]["task"] == task]
        seeds = {r["seed"] for r, _, _ in mine}
        for arch, length in dict.fromkeys((r["arch"], r["length"]) for r, _, _ in mine):
            have = {(r["kind"], r["seed"]) for r, _, _ in mine if (r["arch"], r["length"]) == (arch, length)}
            missing = sorted({(k, s) for k in kinds for s in seeds} - have)
            if missing:
                raise PipelineError(f"--run: task {task}, '{arch}' at L = {length} has no run of {missing[0][0]} "
                                    f"with seed {missing[0][1]}: the runs must fill the grid of operators x seeds")
        first_row, recipes[task], first_run = mine[0]
        for r, recipe, run in mine:
            differing = [key for key in RECIPE if recipe[key] != recipes[task][key]]
            if differing:
                raise PipelineError(f"{run[3]}, {first_run[3]}: trained with different {differing[0]}: not the same "
                                    f"recipe (only the architecture, convolution, width and seed may differ)")
            if any(not np.allclose(r[name], first_row[name], rtol=1e-6, equal_nan=True)
                   for name in COLUMNS if name.startswith("loop_")):
                raise PipelineError(f"{run[2]}, {first_run[2]}: their predictor errors differ: not evaluations of "
                                    f"the same frames")
    devices = " / ".join(sorted({r["device"] for r, _, _ in read}))
    return Convs({name: np.array([r[name] for r, _, _ in read]) for name in COLUMNS}, devices, recipes), recipes


def recipe_words(recipes: dict[str, dict], seeds: list[int]) -> str:
    """How each task's runs were trained, from their train.h5 (they all agree), for the report."""
    lines = []
    for task, recipe in recipes.items():
        loss = f"{recipe['loss_l1']} L1 + {recipe['loss_l2']} L2 + {recipe['loss_normal']} normal"
        lines.append(f"- {task}: trained on `{recipe['dataset']}`, {recipe['epochs']} epochs of batch "
                     f"{recipe['batch_size']} (share {recipe['sample_share']} of the frames an epoch), Adam at "
                     f"{recipe['lr']} ({recipe['lr_schedule']}), loss {loss}, {recipe['pool']} pooling, inputs "
                     f"{recipe['inputs']} ({recipe['input_frame']} frame in, {recipe['output_frame']} out).")
    return ("Every run of a task: the same data, steps and recipe (checked from each run's train.h5); only the "
            f"operator, filter length, architecture and seed differ. Seeds: {', '.join(map(str, seeds))} (the "
            "network's initial weights and the order of the frames).\n\n" + "\n".join(lines))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.convs", description=__doc__.splitlines()[0])
    parser.add_argument("table", help="convs.h5 to write")
    parser.add_argument("chart", help="bar chart (PNG) to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("html", help="report.html to write")
    parser.add_argument("--run", nargs=4, action="append", default=[], metavar=("TASK", "SEED", "EVAL.h5", "TRAIN.h5"))
    parser.add_argument("--part", action="append", default=[], metavar="CONVS.h5",
                        help="the convs.h5 of a part of the grid run elsewhere (other seeds): its rows join the table")
    parser.add_argument("--scene-report", help="the scene's report.md, linked from the report")
    args = parser.parse_args(argv)
    outputs = {"CONVS.h5": args.table, "CHART.png": args.chart, "REPORT.md": args.report, "REPORT.html": args.html}
    cli.refuse_aliases(outputs, {**{f"{name} {i}": path for i, run in enumerate(args.run)
                                    for name, path in (("EVAL.h5", run[2]), ("TRAIN.h5", run[3]))},
                                 **{f"--part {i}": path for i, path in enumerate(args.part)}})
    table, recipes = gather([tuple(run) for run in args.run], args.part)
    write_convs(args.table, {"runs": [list(run) for run in args.run], "parts": args.part, "recipes": recipes}, table)
    with atomic_write(args.chart) as f:
        f.write(chart_png(table))
    report = Path(args.report)
    href = lambda path: os.path.relpath(path, report.parent)      # noqa: E731
    links = ([("the scene's report", href(args.scene_report))] if args.scene_report else []) + [
        ("convs.h5: every run's errors, parameters and inference time", href(args.table))] + [
        (f"{os.path.relpath(Path(path).parent, Path(args.table).parent)}: the run's report",
         href(Path(path).parent / "report.md")) for _, _, path, _ in args.run] + [
        (f"{path}: the rows of a part of the grid run elsewhere", href(path)) for path in args.part]
    pieces = sections(table, Path(args.chart), links,
                      recipe_words(recipes, sorted(set(table.columns["seed"].tolist()))))
    title = "Operator comparison: " + ", ".join(kind for kind in KINDS if kind in set(table.columns["kind"]))
    markdown, page = report_markdown(title, pieces, href), report_html(title, pieces)
    with atomic_write(args.report) as f:
        f.write(markdown.encode())
    with atomic_write(args.html) as f:
        f.write(page.encode())


def chart_png(table: Convs) -> bytes:
    """One panel per task: held-out L1 where the task has a held-out motion (what a user meets), else test L1."""
    panels = []
    for task in dict.fromkeys(table.columns["task"]):
        chosen = [row for row in rows(table) if row.task == task]
        split = next(s for s in ("heldout", "test") if f"l1_{s}" in chosen[0].values)
        words = {"heldout": "held-out", "test": "test"}[split]
        panels.append((f"{TASK_WORDS[task].split(' (')[0]}: {words} L1",
                       [f"{row.arch}\nx{row.width:g}, L = {row.length}" for row in chosen],
                       {kind: np.array([row.values[f"l1_{split}"][kind] for row in chosen]) / PAPER_UNIT
                        for kind in chosen[0].kinds},
                       chosen[0].loop[f"l1_{split}"] / PAPER_UNIT))
    return convs_plot(panels)
