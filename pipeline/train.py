"""Stage `train`: fit the upsampling network to a dataset on a mesh's operators → model.pt + train.h5.

    python -m pipeline.train DATASET.h5 OPERATORS.h5 MODEL.pt TRAIN.h5 --arch "D62 D124 D248 D D248 D_3 D248"
        [--conv RC13] [--pool avg] [--width 1.0] [--epochs 200] [--batch-size 3] [--lr 1e-3] [--loss-l1 1]
        [--loss-l2 0] [--loss-normal 0] [--device cpu] [--seed 0] [--checkpoint PATH] [--threads N] [--quiet]

A checkpoint (default MODEL.pt.ckpt) is written after every epoch; rerunning the same command after a kill
resumes from it (bit for bit on the same device and thread count), and it is removed once model.pt and train.h5
are complete. model.pt holds the state dict and everything needed to rebuild the network and to recognise the
operators it was trained on (docs/artifacts.md).
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm import tqdm

from model.architecture import ArchitectureError
from model.mesh_hierarchy import MeshHierarchy, mesh_hierarchy
from model.losses import LossWeights
from model.networks import NetworkSpec, NormalizedRegressor, build_network
from model.training import Frames, TrainSettings, fit
from pipeline import cli
from pipeline.artifacts.h5 import atomic_h5, open_artifact, read
from pipeline.errors import PipelineError

MODEL_FORMAT = "trimesh-cnn/model-1"


@dataclasses.dataclass(frozen=True)
class LearningData:
    """The dataset artifact's arrays: inputs (= predictor) and target displacements, faces, split."""

    inputs: np.ndarray
    targets: np.ndarray
    faces: np.ndarray
    train: np.ndarray
    test: np.ndarray
    fingerprint: str
    held_out: np.ndarray   # frames of motions never trained on (may be empty)

    def splits(self) -> dict[str, np.ndarray]:
        """The non-empty splits by name."""
        named = {"train": self.train, "test": self.test, "held_out": self.held_out}
        return {name: ids for name, ids in named.items() if len(ids)}

    def frames(self, device: torch.device | str) -> Frames:
        return Frames(torch.as_tensor(self.inputs, device=device), torch.as_tensor(self.targets, device=device),
                      torch.as_tensor(self.faces.astype(np.int64), device=device))


def load_dataset(path: str) -> LearningData:
    with open_artifact(path) as f:
        inputs, targets = read(f, "input", np.float32), read(f, "target", np.float32)
        faces = read(f, "faces", np.int64)
        train, test = read(f, "split/train", np.int64), read(f, "split/test", np.int64)
        held_out = read(f, "split/held_out", np.int64) if "split/held_out" in f else np.zeros(0, np.int64)
    if inputs.shape != targets.shape or inputs.ndim != 3:
        raise PipelineError(f"{path}: 'input' {inputs.shape} and 'target' {targets.shape} must both be (F, V, 3)")
    every = np.concatenate([train, test, held_out])
    if len(train) == 0 or len(test) == 0 or len(np.unique(every)) != len(every) or every.max() >= len(inputs):
        raise PipelineError(f"{path}: 'split/train', 'split/test' (and 'split/held_out') must be disjoint frame ids, "
                            f"train and test non-empty")
    digest = hashlib.sha256(inputs.tobytes())
    digest.update(targets.tobytes())
    digest.update(train.tobytes())
    return LearningData(inputs, targets, faces, train, test, digest.hexdigest(), held_out)


def load_hierarchy(path: str, conv: str, n_levels: int, faces: np.ndarray | None = None) -> MeshHierarchy:
    """Levels 0..n_levels-1 of an operators artifact with the `conv` tables; with `faces`, check that level 0
    is that mesh."""
    with open_artifact(path) as f:
        if "levels" not in f:
            raise PipelineError(f"{path}: no 'levels' group (not an operators file)")
        available = len(f["levels"])
        if n_levels > available:
            raise PipelineError(f"{path}: the architecture needs {n_levels} mesh levels ({n_levels - 1} poolings), "
                                f"the file has {available} (rebuild the operators with --levels {n_levels - 1} "
                                f"or more)")
        if f"levels/0/conv/{conv}" not in f:
            kinds = sorted(f["levels/0/conv"]) if "levels/0/conv" in f else []
            raise PipelineError(f"{path}: no '{conv}' convolution tables (the file has {', '.join(kinds) or 'none'})")
        tables = [read(f, f"levels/{i}/conv/{conv}", np.int64) for i in range(n_levels)]
        pools = [read(f, f"levels/{i}/pool", np.int64) for i in range(n_levels - 1)]
        unpools = [read(f, f"levels/{i}/unpool", np.int64) for i in range(n_levels - 1)]
        level0_faces = read(f, "levels/0/faces", np.int64)
    if faces is not None and not np.array_equal(level0_faces, faces):
        raise PipelineError(f"{path}: level 0 is not the dataset's mesh (different faces)")
    try:
        return mesh_hierarchy(tables, pools, unpools)
    except ValueError as err:
        raise PipelineError(f"{path}: {err}") from None


def save_model(path: Path, model: NormalizedRegressor, spec: NetworkSpec, mesh: MeshHierarchy,
               extra: dict[str, Any]) -> None:
    state = {"format": MODEL_FORMAT, "spec": dataclasses.asdict(spec), "state_dict": model.state_dict(),
             "arch_expanded": str(model.net.arch), "parameter_count": model.net.parameter_count(),
             "operators": {"fingerprint": mesh.fingerprint(), "vertex_counts": mesh.vertex_counts}, **extra}
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_model(path: str, operators_path: str, device: str) -> tuple[NormalizedRegressor, MeshHierarchy, dict]:
    """A trained model and the hierarchy it runs on, after checking the operators are those it was trained on."""
    if not Path(path).is_file():
        raise PipelineError(f"{path}: model file does not exist")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a corrupt or foreign file
        raise PipelineError(f"{path}: not a readable model file ({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != MODEL_FORMAT:
        raise PipelineError(f"{path}: not a model written by pipeline.train (format {MODEL_FORMAT})")
    spec = NetworkSpec(**state["spec"])
    trained = state["operators"]
    mesh = load_hierarchy(operators_path, spec.conv, len(trained["vertex_counts"]))
    if mesh.vertex_counts != trained["vertex_counts"]:
        raise PipelineError(f"{operators_path}: the model in {path} was trained on a mesh hierarchy with vertex "
                            f"counts {trained['vertex_counts']}, these operators have {mesh.vertex_counts}")
    if mesh.fingerprint() != trained["fingerprint"]:
        raise PipelineError(f"{operators_path}: same vertex counts but different operator tables than the ones "
                            f"the model in {path} was trained on")
    net = build_network(spec)
    model = NormalizedRegressor(net, torch.zeros(spec.in_channels), 1.0, 1.0)
    model.load_state_dict(state["state_dict"])
    return model.to(device).eval(), mesh.to(device), state


def configure_torch(device: str, seed: int, threads: int | None = None) -> torch.device:
    """Deterministic, seeded torch on `device` using `threads` CPU threads (default: torch's choice); fails
    clearly if CUDA is asked for but absent."""
    if threads is not None:
        if threads < 1:
            raise PipelineError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise PipelineError(f"device '{device}' requested but torch finds no CUDA device (use --device cpu)")
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")   # deterministic cuBLAS
    torch.use_deterministic_algorithms(True)
    torch.set_flush_denormal(True)     # denormals in Adam's moments make CPU matmuls ~20x slower
    torch.manual_seed(seed)
    return torch.device(device)


def add_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threads", type=int, help="CPU threads for torch (Snakemake: the rule's threads)")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.train", description=__doc__.splitlines()[0])
    parser.add_argument("dataset"), parser.add_argument("operators")
    parser.add_argument("model", help="model.pt to write"), parser.add_argument("log", help="train.h5 to write")
    parser.add_argument("--arch", required=True, help="architecture, e.g. 'D62 D124 D248 D D248 D_3 D248'")
    parser.add_argument("--conv", default="RC13", help="operator tables to use: RC|EC|SP|SPD + size")
    parser.add_argument("--pool", default="avg", choices=["avg", "max"])
    parser.add_argument("--width", type=float, default=1.0, help="channel multiplier (paper x/2: 0.5)")
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--batch-size", type=int, default=3)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--loss-l1", type=float, default=1.0, help="alpha of eq. 7")
    parser.add_argument("--loss-l2", type=float, default=0.0, help="beta of eq. 7")
    parser.add_argument("--loss-normal", type=float, default=0.0, help="gamma of eq. 7")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint", help="per-epoch checkpoint (default MODEL.pt.ckpt)")
    add_threads(parser)
    cli.add_quiet(parser)
    args = parser.parse_args(argv)
    if args.epochs < 1 or args.batch_size < 1 or not args.lr > 0:
        raise PipelineError("--epochs and --batch-size must be >= 1 and --lr > 0")
    if min(args.loss_l1, args.loss_l2, args.loss_normal) < 0:
        raise PipelineError("loss weights must be >= 0")
    device = configure_torch(args.device, args.seed, args.threads)
    data = load_dataset(args.dataset)
    spec = NetworkSpec(args.arch, args.conv, args.pool, args.width, data.inputs.shape[2], data.targets.shape[2])
    if spec.letter != "D":
        raise PipelineError(f"--arch '{args.arch}': the upsampling network is an encoder-decoder, written with "
                            f"D tokens (e.g. 'D62 D124 D248 D D248 D_3 D248')")
    try:
        net = build_network(spec)
    except ArchitectureError as err:
        raise PipelineError(f"--arch/--conv/--pool/--width: {err}") from None
    mesh = load_hierarchy(args.operators, args.conv, net.n_levels, data.faces)
    try:
        net.check_mesh(mesh)
    except ValueError as err:
        raise PipelineError(f"{args.operators}: {err}") from None
    model = _normalized(net, data)
    settings = TrainSettings(args.epochs, args.batch_size, args.lr,
                             LossWeights(args.loss_l1, args.loss_l2, args.loss_normal), args.seed)
    checkpoint = Path(args.checkpoint or f"{args.model}.ckpt")
    for folder in (checkpoint.parent, Path(args.model).parent):
        folder.mkdir(parents=True, exist_ok=True)
    steps_per_epoch = -(-len(data.train) // args.batch_size)
    start = time.perf_counter()
    with tqdm(total=args.epochs * steps_per_epoch, desc="train", unit="batch", disable=args.quiet) as bar:
        def on_batch(epoch: int, loss: float) -> None:
            if bar.n == 0:
                bar.update(epoch * steps_per_epoch)      # a resumed run starts past the checkpointed epochs
            bar.update()
            bar.set_postfix_str(f"epoch {epoch + 1}/{args.epochs} loss {loss:.3e}")

        history = fit(model.to(device), mesh.to(device), data.frames(device),
                      torch.as_tensor(data.train, device=device), torch.as_tensor(data.test, device=device),
                      settings, checkpoint, {"dataset": data.fingerprint, "operators": mesh.fingerprint(),
                                             "spec": dataclasses.asdict(spec)}, on_batch, bar.write)
    seconds = time.perf_counter() - start
    config = {**vars(args), "parameter_count": net.parameter_count()}
    training = {"epochs": args.epochs, "batch_size": args.batch_size, "lr": args.lr, "seed": args.seed,
                "device": str(device), "loss_weights": dataclasses.asdict(settings.weights),
                "final_train_loss": history.train["total"][-1], "final_test_loss": history.test["total"][-1],
                "dataset": args.dataset, "dataset_fingerprint": data.fingerprint}
    save_model(Path(args.model), model.cpu(), spec, mesh, {"training": training})
    _write_log(args.log, history, config, str(device), net.parameter_count(), seconds)
    checkpoint.unlink(missing_ok=True)


def _normalized(net, data: LearningData) -> NormalizedRegressor:
    """Fixed input/output normalisation from the training frames only."""
    train_inputs, train_targets = data.inputs[data.train], data.targets[data.train]
    offset = train_inputs.reshape(-1, train_inputs.shape[2]).mean(axis=0)
    input_scale = float(np.sqrt(np.mean(np.square(train_inputs - offset)))) or 1.0
    output_scale = float(np.sqrt(np.mean(np.square(train_targets)))) or 1.0
    return NormalizedRegressor(net, torch.as_tensor(offset), input_scale, output_scale)


def _write_log(path: str, history, config: dict, device: str, n_params: int, seconds: float) -> None:
    with atomic_h5(path, "train", config) as f:
        for split in ("train", "test"):
            for term, values in getattr(history, split).items():
                f.create_dataset(f"epoch/{split}_{term}", data=np.asarray(values, dtype=np.float64))
        f.create_dataset("epoch/seconds", data=np.asarray(history.epoch_seconds))
        f.create_dataset("batch/total", data=np.asarray(history.batch_total, dtype=np.float64))
        f.attrs.update(device=device, parameter_count=n_params, epochs=history.epochs_done,
                       resumed_from_epoch=history.resumed_from_epoch, wall_seconds=seconds,
                       loss_unit="scene units (~m); normal term dimensionless")
        f["epoch"].attrs["meaning"] = ("per-epoch mean losses: train_* over the epoch's batches while training, "
                                       "test_* on the test frames after the epoch; total = eq. 7")


if __name__ == "__main__":
    cli.run(main)
