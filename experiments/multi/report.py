"""Stage `multi_report`: one network for many garments against each garment's own network → multi.h5, the
training curve and report.md (paper sec. 7, supplementary Table 3).

    python -m experiments.multi.report MULTI.h5 CURVE.png REPORT.md --model MODEL.pt --train-log TRAIN.h5
        --garment NAME SHARED_EVAL.h5 OWN_EVAL.h5 [--garment ...]

MODEL.pt and TRAIN.h5 are the multi-garment model and its training (experiments.multi train). Per garment,
SHARED_EVAL.h5 is the evaluate stage's measure of the shared network on the garment's dataset
(results/multi/<scene>/eval.h5) and OWN_EVAL.h5 that of the garment's own network, trained on it alone with the
same settings (results/<scene>/eval.h5). Both must be the same size of network and measure the same frames
(their Loop subdivision errors agree): anything else is refused, since the table would compare unlike things.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from experiments.multi.model_file import load_multi_model
from experiments.multi.table import NETWORKS, TERMS, WHO, MultiTable, write_multi_table
from pipeline.artifacts.evaluation import read_errors, read_network_timing
from pipeline.artifacts.train_log import read_train_log
from pipeline.core import cli
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import atomic_write
from viz.html_report import Links, Paragraphs, Picture, Section, Table
from viz.markdown_report import report_markdown
from viz.plots import figure_bytes, training_curve

PAPER_UNIT = 1e-3
SPLIT_NAMES = {"train": "train", "test": "test", "held_out": "held-out"}
ROW_NAMES = {"predictor": "Loop subdivision alone", "own": "own network (this garment only)",
             "shared": "shared network (every garment)"}


def gather(state: dict, garments: list[tuple[str, str, str]]) -> MultiTable:
    """The table from the multi-garment model's contents and (name, shared eval.h5, own eval.h5) per garment."""
    names = [name for name, _, _ in garments]
    if sorted(names) != sorted(state["garments"]) or len(set(names)) != len(names):
        raise PipelineError(f"--garment: give each garment of the model once ({', '.join(state['garments'])}), "
                            f"got {', '.join(names)}")
    errors, timing = {}, {}
    for name, shared, own in garments:
        errors[name] = {"shared": read_errors(shared), "own": read_errors(own)}
        timing[name] = {"shared": read_network_timing(shared), "own": read_network_timing(own)}
        size = {who: (t.params, t.name) for who, t in timing[name].items()}
        if size["own"] != size["shared"] or size["shared"][0] != state["parameter_count"]:
            raise PipelineError(f"{own}: the garment's own network has {size['own'][0]:,} parameters "
                                f"({size['own'][1]}), the shared one {state['parameter_count']:,} "
                                f"({size['shared'][1]}): not the same size of network")
        if errors[name]["own"]["predictor"] != errors[name]["shared"]["predictor"]:
            raise PipelineError(f"{own}, {shared}: their Loop subdivision errors differ: not evaluations of the same "
                                f"frames")
    splits = [s for s in SPLIT_NAMES if all(s in errors[n]["own"]["predictor"] for n in names)]
    source = {"predictor": ("own", "predictor"), "own": ("own", "network"), "shared": ("shared", "network")}
    table = {who: {split: {term: np.array([errors[n][source[who][0]][source[who][1]][split][term] for n in names])
                           for term in TERMS} for split in splits} for who in WHO}
    devices = {t.device for n in names for t in timing[n].values()}
    return MultiTable(names, np.array([len(state["garments"][n]["rest"]) for n in names]), splits, table,
                      {who: np.array([float(np.median(timing[n][who].inference_ms)) for n in names])
                       for who in NETWORKS}, state["parameter_count"], timing[names[0]]["shared"].name,
                      " / ".join(sorted(devices)))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.multi.report", description=__doc__.splitlines()[0])
    parser.add_argument("table", help="multi.h5 to write")
    parser.add_argument("curve", help="training curve (PNG) to write")
    parser.add_argument("report", help="report.md to write")
    parser.add_argument("--model", required=True, help="the multi-garment model.pt")
    parser.add_argument("--train-log", required=True, help="its train.h5")
    parser.add_argument("--garment", nargs=3, action="append", required=True,
                        metavar=("NAME", "SHARED_EVAL.h5", "OWN_EVAL.h5"))
    args = parser.parse_args(argv)
    cli.refuse_aliases({"MULTI.h5": args.table, "CURVE.png": args.curve, "REPORT.md": args.report},
                       {"MODEL": args.model, "TRAIN.h5": args.train_log,
                        **{f"shared eval.h5 of {name}": shared for name, shared, _ in args.garment},
                        **{f"own eval.h5 of {name}": own for name, _, own in args.garment}})
    _, state = load_multi_model(args.model)
    table = gather(state, [tuple(g) for g in args.garment])
    log = read_train_log(args.train_log)
    write_multi_table(args.table, {"model": args.model, "train_log": args.train_log,
                                   "garments": [list(g) for g in args.garment]}, table)
    with atomic_write(args.curve) as f:
        f.write(figure_bytes(training_curve(log.train_total, log.test_total, title="Training curve of the shared "
                                            "network (loss = mean over garments of eq. 7)"), "png", dpi=100))
    report = Path(args.report)
    sections = _sections(table, state, args, Path(args.curve), len(log.train_total))
    with atomic_write(report) as f:
        f.write(report_markdown("One network, many garments", sections,
                                lambda path: os.path.relpath(path, report.parent)).encode())


def _sections(table: MultiTable, state: dict, args, curve: Path, epochs: int) -> list[Section]:
    spec, training = state["spec"], state["training"]
    names = ", ".join(table.garments)
    scaled = lambda who, split, term, k: table.errors[who][split][term][k] / PAPER_UNIT  # noqa: E731
    header = ["garment", "", *[f"{SPLIT_NAMES[s]} {t.upper()}" for s in table.splits for t in TERMS]]
    rows = []
    for k, garment in enumerate(table.garments):
        for who in WHO:
            rows.append([garment, ROW_NAMES[who],
                         *[f"{scaled(who, s, t, k):.3f}" for s in table.splits for t in TERMS]])
        for network in NETWORKS:
            rows.append([garment, f"gain of the {network} network (Loop / network)",
                         *[f"{scaled('predictor', s, t, k) / max(scaled(network, s, t, k), 1e-30):.2f}x"
                           for s in table.splits for t in TERMS]])
        rows.append([garment, "shared / own (below 1: sharing helps)",
                     *[f"{scaled('shared', s, t, k) / max(scaled('own', s, t, k), 1e-30):.2f}"
                       for s in table.splits for t in TERMS]])
    timing_rows = [[garment, f"{table.vertices[k]:,}", f"{table.inference_ms['own'][k]:.2f}",
                    f"{table.inference_ms['shared'][k]:.2f}"] for k, garment in enumerate(table.garments)]
    loss = training["loss_weights"]
    training_rows = [["garments", names], ["epochs", epochs],
                     ["samples per epoch (one frame of every garment each)", training.get("samples_per_epoch", "")],
                     ["frames of each garment per step (batch size)", training["batch_size"]],
                     ["Adam learning rate", f"{training['lr']:g}"], ["seed", training["seed"]],
                     ["loss weights L1 / L2 / Ln", f"{loss['l1']:g} / {loss['l2']:g} / {loss['normal']:g}"],
                     ["device", training["device"]]]
    report_dir = Path(args.report).parent
    links = [(f"{g}: the shared network's report", os.path.relpath(Path(shared).parent / "report.md", report_dir))
             for g, shared, _ in args.garment]
    links += [(f"{g}: its own network's report", os.path.relpath(Path(own).parent / "report.md", report_dir))
              for g, _, own in args.garment]
    links += [("multi.h5: this table", os.path.relpath(args.table, report_dir)),
              ("model.pt: the shared network, the garments' mesh constants and operators",
               os.path.relpath(args.model, report_dir)),
              ("train.h5: its loss curves", os.path.relpath(args.train_log, report_dir))]
    return [
        Section("Network", [Paragraphs(
            f"{state['arch_expanded']} (encoder-decoder), conv {spec['conv']}, {spec['pool']} pooling, width "
            f"{spec['width']:g}: **{table.parameters:,} learnable parameters**, one set shared by {names}; each "
            f"garment runs it on its own operator tables (results/<scene>/operators.h5). Each garment's own network "
            f"is the scene's (results/<scene>/model.pt): the same network, {table.parameters:,} parameters, trained "
            f"on that garment alone with the same settings.")]),
        Section("Errors (x 1e-3 scene units, as paper Table 3)", [Table(header, rows), Paragraphs(
            "Each garment's frames as its scene's dataset splits them: held-out = the motion never trained on, test "
            "= a random share of the trained motions' frames. L1 (eq. 4), L2 (eq. 5) over all frames of a split. "
            "gain = Loop subdivision's error / the network's; shared / own = the shared network's error / the "
            "garment's own network's.")]),
        Section("Inference time", [Table(["garment", "high-res vertices", "own network ms", "shared network ms"],
                                         timing_rows), Paragraphs(
            f"Median ms per frame on {table.device} on the deployment path (input features and network, S x_low "
            "given; the garments' evaluate reports say how it was timed). The shared network is the same size as "
            "each own network, so its time per frame is that of a one-garment network on the same mesh.")]),
        Section("Training", [Table(["", "value"], training_rows), Paragraphs(
            "Every optimiser step sees the batch size's frames of every garment; its loss is the mean over "
            "garments of each garment's eq. 7 over its frames, so each garment weighs the same whatever its vertex "
            "count. One normalisation serves every garment (their statistics averaged). An epoch shows every "
            "training frame of every garment at least once (a garment with fewer frames repeats some), so each "
            "garment is seen as often as by its own network in the same number of epochs."),
            Picture(curve, "Loss per epoch, train and test (mean over garments; log scale).")]),
        Section("Files", [Links(links)]),
    ]


if __name__ == "__main__":
    cli.run(main)
