"""Stage `multi`: one upsampling network with shared weights trained on several garments (paper sec. 7,
supplementary Table 3) → the multi-garment model.pt, its train.h5 and, per garment, a view: a model.pt of
pipeline.train's format that `evaluate` (and export_model, deploy/) runs as any scene's model.

    python -m experiments.multi train MODEL.pt TRAIN.h5 --garment NAME SETTINGS.json DATASET.h5 OPERATORS.h5 VIEW.pt
        [--garment ...] [--checkpoint PATH] [--threads N] [--quiet]
    python -m experiments.multi view MODEL.pt NAME OPERATORS.h5 VIEW.pt

train: each garment is a scene's upsampling dataset, operators and settings.json. Network (`network.*`), training
(`training.*`) and device are read from the garments' settings.json, which must agree on them: the shared
network is then the same size, and trained with the same recipe, as each garment's own (results/<scene>/model.pt),
so the comparison is between like and like. Every optimiser step sees a batch of `training.batch_size` frames of
every garment and the loss is the mean over garments of each garment's own batch loss; an epoch shows every
garment's training frames at least once (model/multi_mesh.py says why). A checkpoint (default MODEL.pt.ckpt) is
written after every epoch and a rerun resumes from it, as pipeline.train's.

view: the network of MODEL.pt for garment NAME (as `train` writes for each garment), refusing a garment the model
was not trained on, and operators other than those it was trained with for that garment.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any, Sequence

import torch

from experiments.multi.model_file import (check_garment_operators, load_multi_model, save_garment_view,
                                          save_multi_model, trained_operators)
from model.architecture import ArchitectureError
from model.feature_spec import FeatureSpec
from model.losses import LossWeights
from model.mesh_hierarchy import MeshHierarchy
from model.multi_mesh import Garment, MultiMeshFrames, MultiMeshRegressor
from model.networks import MeshNetwork, NetworkSpec, build_network
from model.training import CheckpointError, TrainSettings, fit
from pipeline.artifacts.dataset import UPSAMPLING, LearningData, load_dataset
from pipeline.artifacts.model import read_checkpoint, write_checkpoint
from pipeline.artifacts.operators import load_hierarchy
from pipeline.artifacts.train_log import write_train_log
from pipeline.core import cli
from pipeline.core.config import feature_spec, read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.progress import batch_reporter, training_bar
from pipeline.core.torch_setup import configure_torch
from pipeline.tasks import TASKS, frames_of

SHARED = ("network", "training", "device")     # what the garments' settings must agree on


@dataclasses.dataclass(frozen=True)
class GarmentFiles:
    name: str
    settings: str
    dataset: str
    operators: str
    view: str


def shared_settings(garments: Sequence[GarmentFiles]) -> dict[str, Any]:
    """network, training and device of the garments' settings.json, which must agree; one error naming the
    first setting that differs otherwise."""
    first, *others = garments
    reference = read_settings(first.settings)
    for garment in others:
        settings = read_settings(garment.settings)
        for key in SHARED:
            where = _first_difference(reference[key], settings[key], key)
            if where is not None:
                raise PipelineError(f"{garment.settings}: {where} differs from {first.settings}'s: the garments of "
                                    f"one network must share {', '.join(f'{k}.*' for k in SHARED[:2])} and device")
    return {key: reference[key] for key in SHARED}


def _first_difference(a: Any, b: Any, where: str) -> str | None:
    """The dotted key of the first value that differs between two settings trees, with both values."""
    if isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys():
        return next((d for k in a if (d := _first_difference(a[k], b[k], f"{where}.{k}")) is not None), None)
    return None if a == b else f"{where} {b!r} (not {a!r})"


def _garment_features(garment: GarmentFiles, data: LearningData, network: dict) -> FeatureSpec:
    """The shared network's per-vertex inputs as the settings `network.*` name them, checked against what the
    garment's dataset holds: an upsampling dataset, with the mannequin that input 'body' needs."""
    if data.task != UPSAMPLING:
        raise PipelineError(f"{garment.dataset}: a dataset of task '{data.task}'; one network for many garments "
                            f"learns the upsampling")
    return feature_spec(network, data.has_body, f"{garment.settings}: network")


def _network(network: dict, features: FeatureSpec, where: str) -> tuple[NetworkSpec, MeshNetwork]:
    """The shared network (freshly initialised from torch's seeded generator, as pipeline.train's) reading
    `features`, and its spec, as the settings `network.*` describe it; one error naming `where` for settings that
    do not make the upsampling task's network."""
    kind = TASKS[UPSAMPLING].network
    kind.check(network["arch"], f"{where}: network: arch '{network['arch']}': the upsampling network is {kind}")
    try:
        spec = NetworkSpec(network["arch"], network["conv"], network["pool"], float(network["width"]),
                           features.channels)
        return spec, build_network(spec)
    except (ValueError, ArchitectureError) as err:
        raise PipelineError(f"{where}: network: {err}") from None


def _garment_mesh(garment: GarmentFiles, data: LearningData, spec: NetworkSpec, net: MeshNetwork) -> MeshHierarchy:
    """The levels of the garment's operators the network runs on."""
    mesh = load_hierarchy(garment.operators, spec.conv, net.n_levels, data.faces, garment.dataset)
    try:
        net.check_mesh(mesh)
    except ValueError as err:
        raise PipelineError(f"{garment.operators}: {err}") from None
    return mesh


def _train(argv: Sequence[str]) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.multi train", description=__doc__.splitlines()[0])
    parser.add_argument("model", help="multi-garment model.pt to write")
    parser.add_argument("log", help="train.h5 to write")
    parser.add_argument("--garment", nargs=5, action="append", required=True,
                        metavar=("NAME", "SETTINGS.json", "DATASET.h5", "OPERATORS.h5", "VIEW.pt"),
                        help="a garment: its name, the scene's settings.json, dataset.h5 and operators.h5, and "
                             "where to write its view (repeat per garment)")
    parser.add_argument("--checkpoint", help="per-epoch checkpoint (default MODEL.pt.ckpt)")
    cli.add_threads(parser)
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    garments = [GarmentFiles(*values) for values in args.garment]
    if len({g.name for g in garments}) != len(garments):
        raise PipelineError("--garment: give each garment once")
    checkpoint = Path(args.checkpoint or f"{args.model}.ckpt")
    cli.refuse_aliases({"MODEL": args.model, "LOG": args.log, "--checkpoint": checkpoint,
                        **{f"VIEW of {g.name}": g.view for g in garments}},
                       {f"{role} of {g.name}": getattr(g, role) for g in garments
                        for role in ("settings", "dataset", "operators")})
    shared = shared_settings(garments)
    training = shared["training"]
    device = configure_torch(shared["device"], training["seed"], args.threads,
                             deterministic=bool(training["deterministic"]), tf32=bool(training["tf32"]),
                             cuda_graph=bool(training["cuda_graph"]))
    datasets = {g.name: load_dataset(g.dataset) for g in garments}
    # The garments share `network.*` (shared_settings), so their inputs are one spec, checked on each garment's data.
    features, *_ = [_garment_features(g, datasets[g.name], shared["network"]) for g in garments]
    spec, net = _network(shared["network"], features, garments[0].settings)
    meshes = {g.name: _garment_mesh(g, datasets[g.name], spec, net) for g in garments}
    parts = [Garment(g.name, frames_of(datasets[g.name], device), meshes[g.name].to(device),
                     torch.as_tensor(datasets[g.name].train, device=device),
                     torch.as_tensor(datasets[g.name].test, device=device)) for g in garments]
    model = MultiMeshRegressor(net, features, {name: (data.faces, data.rest_vertices)
                                               for name, data in datasets.items()}).to(device)
    model.normalise(parts)
    problem = MultiMeshFrames(parts)
    loss = training["loss"]
    settings = TrainSettings(int(training["epochs"]), int(training["batch_size"]), float(training["lr"]),
                             LossWeights(float(loss["l1"]), float(loss["l2"]), float(loss["normal"])),
                             int(training["seed"]), bool(training["cuda_graph"]), float(training["input_noise"]),
                             str(training["lr_schedule"]))
    identity = {"garments": {name: {"dataset": datasets[name].fingerprint, "operators": meshes[name].fingerprint()}
                             for name in meshes},
                "spec": dataclasses.asdict(spec), "features": dataclasses.asdict(features)}
    steps_per_epoch = -(-len(problem.train_samples) // settings.batch_size)
    start = time.perf_counter()
    with training_bar("multi", settings.epochs, steps_per_epoch, args.quiet) as bar:
        on_batch = batch_reporter(bar, settings.epochs, steps_per_epoch)
        try:
            history = fit(model, problem.meshes, problem, problem.train_samples, problem.test_samples, settings,
                          read_checkpoint(checkpoint), lambda state: write_checkpoint(checkpoint, state), identity,
                          on_batch, lambda notice: bar.write(f"{checkpoint}: {notice}"))
        except CheckpointError as err:
            raise PipelineError(f"{checkpoint}: {err}") from None
    seconds = time.perf_counter() - start
    record = {"epochs": settings.epochs, "batch_size": settings.batch_size, "lr": settings.lr, "seed": settings.seed,
              "device": str(device), "loss_weights": dataclasses.asdict(settings.weights),
              "final_train_loss": history.train["total"][-1], "final_test_loss": history.test["total"][-1],
              "garments": [g.name for g in garments], "datasets": {g.name: g.dataset for g in garments},
              "samples_per_epoch": len(problem.train_samples),
              "batching": "every step: batch_size frames of every garment; loss = mean over garments"}
    model.cpu()
    written: list[Path] = []
    try:
        for garment in garments:
            save_garment_view(garment.view, model, garment.name, spec, meshes[garment.name], record)
            written.append(Path(garment.view))
        save_multi_model(args.model, model, spec, meshes, {n: d.fingerprint for n, d in datasets.items()}, record)
        written.append(Path(args.model))
        config = {"garments": [dataclasses.asdict(g) for g in garments], **shared,
                  "parameter_count": net.parameter_count()}
        write_train_log(args.log, history, config, str(device), net.parameter_count(), seconds)
    except BaseException:
        for path in written:         # the outputs come together, or not at all
            path.unlink(missing_ok=True)
        raise
    checkpoint.unlink(missing_ok=True)


def _view(argv: Sequence[str]) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.multi view",
                                     description="one garment's network of a multi-garment model, as a model.pt")
    parser.add_argument("model", help="multi-garment model.pt")
    parser.add_argument("garment", help="the garment's name, as trained")
    parser.add_argument("operators", help="the garment's operators.h5")
    parser.add_argument("view", help="model.pt to write")
    args = parser.parse_args(argv)
    cli.refuse_aliases({"VIEW": args.view}, {"MODEL": args.model, "OPERATORS": args.operators})
    model, state = load_multi_model(args.model)
    n_levels = len(trained_operators(args.model, state, args.garment)["vertex_counts"])
    mesh = load_hierarchy(args.operators, state["spec"]["conv"], n_levels)
    check_garment_operators(args.model, state, args.garment, mesh, args.operators)
    save_garment_view(args.view, model, args.garment, NetworkSpec(**state["spec"]), mesh, state["training"])


COMMANDS = {"train": _train, "view": _view}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.multi", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=sorted(COMMANDS))
    parser.add_argument("arguments", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    COMMANDS[args.command](args.arguments)

