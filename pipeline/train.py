"""Stage `train`: fit a task's network to a dataset on a mesh's operators → model.pt + train.h5.

    python -m pipeline.train DATASET.h5 OPERATORS.h5 MODEL.pt TRAIN.h5 [--settings SETTINGS.json]
        --arch "D62 D124 D248 D D248 D_3 D248" [--conv RC13] [--pool avg] [--width 1.0]
        [--inputs position,...] [--input-frame dataset|local] [--output-frame dataset|local]
        [--frame-tangent edge|gravity] [--epochs 200]
        [--batch-size 3] [--lr 1e-3] [--loss-l1 1] [--loss-l2 0] [--loss-normal 0] [--device cpu] [--seed 0]
        [--cuda-graph true|false] [--input-noise 0] [--lr-schedule constant|cosine] [--checkpoint PATH]
        [--sample-share 1] [--sample-block 1] [--sample-buffer 4096] [--device-cache-gb GB]
        [--train-on train[,held_out]] [--threads N] [--quiet]

    torchrun --nproc_per_node=N -m pipeline.train ...   (the same flags: N ranks, --batch-size frames each)

A checkpoint (default MODEL.pt.ckpt) is written after every epoch; rerunning the same command after a kill
resumes from it (bit for bit on the same device and thread count), and it is removed once model.pt and train.h5
are complete. A file at the checkpoint path that is not a checkpoint is refused, not overwritten, and so is a
checkpoint path equal to any other input or output. The dataset's task (pipeline/tasks) picks the network: the
upsampling's encoder-decoder (D tokens) or a decoder (U tokens, e.g. 'U208 U U208 U U208 U U208 U104 U52 U3') from
the pose or PCA task's input vector onto the coarsest level its tokens reach. The encoder-decoder sees the per-vertex features named by --inputs
(model.features: the paper's absolute positions, or velocity, body, laplacian, gravity... relative to the body and
the local surface), optionally in each vertex's local frame, and may answer in local frames too. model.pt holds
the state dict and everything needed to rebuild the network and its inputs and to recognise the operators it was
trained on (docs/artifacts.md), and which sequences (library files, subjects) it was trained on.

Each epoch visits --sample-share of the training frames, drawn in blocks of --sample-block consecutive frames
and shuffled --sample-buffer frames at a time (model.sampler; the defaults: every frame, in one random order).
The frames stay on the device as long as x_low and the targets fit --device-cache-gb (default: half the device's
free memory, or on the CPU half the available RAM); a larger dataset is streamed from disk a batch at a time by
a background thread (model.streaming), with the same arithmetic. --train-on train,held_out trains on the held-out
frames too: an oracle whose held-out error is what the architecture can reach on that motion, which model.pt and
the evaluation's report say. With --settings (a
scene's resolved settings.json), `network.*`, `training.*` (loss weights from `training.loss`) and `device` are
the defaults of the flags of the same names, --arch included.

Under torchrun (or any launcher that sets WORLD_SIZE, RANK, LOCAL_RANK, MASTER_ADDR and MASTER_PORT) the ranks
train together with DistributedDataParallel (model.data_parallel): NCCL on CUDA, one GPU a rank (cuda:LOCAL_RANK,
or a free one of the workflow's shared pool), gloo on the CPU. Every step takes --batch-size frames of each rank,
so N ranks train the model one process trains at N x --batch-size, up to rounding; rank 0 alone shows progress
and writes the checkpoint, model.pt and train.h5, and a rerun resumes from the checkpoint with the same N.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from model import data_parallel
from model.autoregressive import reads_previous_output
from model.data_parallel import Ranks
from model.feature_spec import FEATURE_CHANNELS, FRAMES, TANGENTS
from model.losses import LossWeights
from model.sampler import Sampler, SampleSettings
from model.training import CheckpointError, Diverged, TrainSettings, fit, split_batch_size
from model.training_step import LR_SCHEDULES
from pipeline.artifacts.dataset import (SPLIT_NAMES_TRAINED, FrameReader, LearningData, load_dataset,
                                        read_frame_origins, read_library_windows)
from pipeline.artifacts.model import read_checkpoint, save_model, write_checkpoint
from pipeline.artifacts.train_log import write_train_log
from pipeline.core import cli, gpu_slots
from pipeline.core.errors import PipelineError
from pipeline.core.progress import batch_reporter, training_bar
from pipeline.core.torch_setup import configure_torch
from pipeline.tasks import streams_frames, task_of
from pipeline.tasks.task import NetworkRequest

MAX_LR = 1.0       # the schema's training.lr maximum: beyond it Adam's first steps overflow the weights


def flags_from_settings(settings: dict) -> dict[str, Any]:
    network, training = settings["network"], settings["training"]
    return {"arch": network["arch"], "conv": network["conv"], "pool": network["pool"], "width": network["width"],
            "inputs": network["inputs"], "input_frame": network["input_frame"],
            "output_frame": network["output_frame"], "frame_tangent": network["frame_tangent"],
            "epochs": training["epochs"], "batch_size": training["batch_size"], "lr": training["lr"],
            "seed": training["seed"], "loss_l1": training["loss"]["l1"], "loss_l2": training["loss"]["l2"],
            "loss_normal": training["loss"]["normal"], "cuda_graph": training["cuda_graph"],
            "input_noise": training["input_noise"], "lr_schedule": training["lr_schedule"],
            "deterministic": training["deterministic"], "tf32": training["tf32"], "device": settings["device"],
            "sample_share": training["sample_share"], "sample_block": training["sample_block"],
            "sample_buffer": training["sample_buffer"], "device_cache_gb": training["device_cache_gb"],
            "train_on": training["train_on"]}


def split_list(text: str) -> list[str]:
    """--train-on's comma-separated splits, each once, among those a model may be trained on."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names or len(set(names)) != len(names) or not set(names) <= set(SPLIT_NAMES_TRAINED) \
            or "train" not in names:
        raise argparse.ArgumentTypeError(f"'{text}': train, optionally with held_out")
    return names


def trained_frames(data: LearningData, train_on: list[str], dataset: str) -> np.ndarray:
    """The frame ids trained on, in file order: the train split, and the held-out frames if asked for."""
    if "held_out" in train_on and not len(data.held_out):
        raise PipelineError(f"--train-on {','.join(train_on)}: {dataset} has no held-out frames")
    return np.sort(np.concatenate([data.train, data.held_out if "held_out" in train_on else data.held_out[:0]]))


def sequences_within(data: LearningData, ids: np.ndarray, budget: int, seed: int) -> np.ndarray:
    """The frames of whole training sequences, drawn in a seeded order, while their total stays within `budget`
    (at least one sequence): less of the same motion, for the gain against training frames. Held-out frames among
    `ids` (an oracle's) are all kept."""
    held = np.isin(ids, data.held_out)
    sequences, sizes = np.unique(data.sequence[ids[~held]], return_counts=True)
    order = np.random.default_rng(seed).permutation(len(sequences))
    kept = sequences[order[:max(1, int(np.searchsorted(np.cumsum(sizes[order]), budget, side="right")))]]
    return ids[held | np.isin(data.sequence[ids], kept)]


def same_steps(every: int, kept: int, epochs: int, sampling: SampleSettings) -> tuple[int, SampleSettings]:
    """Epochs and sampling over `kept` frames that visit as many frames as `epochs` of `sampling` over `every`:
    the share rises first (up to every frame an epoch: fewer epochs, fewer per-epoch test passes), then the epochs."""
    target = epochs * Sampler(every, sampling).frames_per_epoch
    share = min(1.0, sampling.share * every / kept)
    raised = dataclasses.replace(sampling, share=share)
    return max(1, round(target / Sampler(kept, raised).frames_per_epoch)), raised


def trained_sequences(dataset: str, data: LearningData, ids: np.ndarray) -> dict[str, list[str]]:
    """The sequences with frames among `ids`: their names and, for a dataset of motion-library windows, each
    one's library file and subject ("" for a sequence that plays none)."""
    which = np.unique(data.sequence[ids])
    names = read_frame_origins(dataset).names
    recorded = {"names": [names[k] for k in which]}
    windows = read_library_windows(dataset)
    if windows is not None:
        recorded.update(library_files=[windows.file[k] for k in which], subjects=[windows.subject[k] for k in which])
    return recorded


def rank_device(ranks: Ranks, device: str) -> str:
    """The device of this process: `device` itself for one process or the CPU; of several ranks on CUDA, a GPU
    each: a free one of the workflow's shared pool taken whole (pipeline.core.gpu_slots; the job asked for a
    GPU's slots a rank), which the rank sees as cuda:0, or else the launcher's GPUs (torchrun's, a Slurm job's),
    one a local rank, whatever index `device` names."""
    if not (ranks.parallel and device.startswith("cuda")):
        return device
    # The GPU whole: every step waits at the all-reduce for the slowest rank, which a neighbouring job would make.
    return "cuda:0" if gpu_slots.claim_gpu(whole=True) is not None else f"cuda:{ranks.local}"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.train", description=__doc__.splitlines()[0])
    parser.add_argument("dataset"), parser.add_argument("operators")
    parser.add_argument("model", help="model.pt to write"), parser.add_argument("log", help="train.h5 to write")
    parser.add_argument("--arch", help="architecture, e.g. 'D62 D124 D248 D D248 D_3 D248' (required)")
    parser.add_argument("--conv", default="RC13", help="operator tables to use: RC|EC|SP|SPD + size")
    parser.add_argument("--pool", default="avg", choices=["avg", "max"])
    parser.add_argument("--width", type=float, default=1.0, help="channel multiplier (paper x/2: 0.5)")
    parser.add_argument("--inputs", default="position",
                        help=f"per-vertex input features, comma-separated, in order: {', '.join(FEATURE_CHANNELS)} "
                             f"(model.features)")
    parser.add_argument("--input-frame", default="dataset", choices=FRAMES,
                        help="vector inputs in the dataset's axes or in each vertex's local frame")
    parser.add_argument("--output-frame", default="dataset", choices=FRAMES,
                        help="the predicted displacement in the dataset's axes or in each vertex's local frame")
    parser.add_argument("--frame-tangent", default="edge", choices=TANGENTS,
                        help="local frames' tangent: a fixed edge, or gravity projected onto the surface")
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--batch-size", type=int, default=3)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--loss-l1", type=float, default=1.0, help="alpha of eq. 7")
    parser.add_argument("--loss-l2", type=float, default=0.0, help="beta of eq. 7")
    parser.add_argument("--loss-normal", type=float, default=0.0, help="gamma of eq. 7")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cuda-graph", type=cli.boolean, default=False, metavar="true|false",
                        help="replay each optimiser step as one CUDA graph (a CUDA device only)")
    parser.add_argument("--lr-schedule", default="constant", choices=LR_SCHEDULES,
                        help="the learning rate over all epochs' steps: constant (paper), or cosine down to 1 %%")
    parser.add_argument("--input-noise", type=float, default=0.0,
                        help="std of Gaussian noise on the normalised inputs while training (0: none)")
    parser.add_argument("--deterministic", type=cli.boolean, default=True, metavar="true|false",
                        help="bit-reproducible on CUDA (sort-based backward of the gathers); false: atomic adds")
    parser.add_argument("--tf32", type=cli.boolean, default=False, metavar="true|false",
                        help="float32 matrix products on TF32 tensor cores (CUDA only)")
    parser.add_argument("--checkpoint", help="per-epoch checkpoint (default MODEL.pt.ckpt)")
    parser.add_argument("--sample-share", type=float, default=1.0,
                        help="share of the training frames each epoch visits (paper: 0.1)")
    parser.add_argument("--sample-block", type=int, default=1, help="consecutive training frames drawn together")
    parser.add_argument("--sample-buffer", type=int, default=4096,
                        help="frames shuffled together after the draw (and read together when streaming)")
    parser.add_argument("--device-cache-gb", type=float,
                        help="GiB of frames kept on the device; a larger dataset is streamed from disk (default: "
                             "half the free memory)")
    parser.add_argument("--train-on", type=split_list, default=["train"], metavar="train[,held_out]",
                        help="the splits trained on; train,held_out: the oracle of the held-out motion")
    parser.add_argument("--train-frames", type=int,
                        help="train on whole training sequences drawn (seeded) up to this many frames, for as many "
                             "optimiser steps as every frame would take (the sample share, then the epochs, raised): "
                             "less of the same motion, nothing else changed (default: every training frame)")
    cli.add_threads(parser)
    cli.add_quiet(parser)
    args = cli.parse_with_settings(parser, argv, flags_from_settings)
    if args.arch is None:    # required, but may come from --settings
        parser.error("the following arguments are required: --arch")
    if args.epochs < 1 or args.batch_size < 1 or not 0 < args.lr <= MAX_LR:
        raise PipelineError(f"--epochs and --batch-size must be >= 1 and --lr in (0, {MAX_LR}]")
    if not all(0 <= w < math.inf for w in (args.loss_l1, args.loss_l2, args.loss_normal)):
        raise PipelineError("loss weights must be finite and >= 0")
    if args.train_frames is not None and args.train_frames < 1:
        raise PipelineError(f"--train-frames {args.train_frames}: give at least 1")
    if not 0 <= args.input_noise < math.inf:
        raise PipelineError("--input-noise must be finite and >= 0")
    try:
        sampling = SampleSettings(args.sample_share, args.sample_block, args.sample_buffer)
    except ValueError:
        raise PipelineError("--sample-share must lie in (0, 1], --sample-block and --sample-buffer be >= 1") from None
    if args.device_cache_gb is not None and not 0 <= args.device_cache_gb < math.inf:
        raise PipelineError("--device-cache-gb must be finite and >= 0")
    checkpoint = Path(args.checkpoint or f"{args.model}.ckpt")
    cli.refuse_aliases({"MODEL": args.model, "LOG": args.log, "--checkpoint": checkpoint},
                       {"DATASET": args.dataset, "OPERATORS": args.operators, "--settings": cli.settings_of(argv)})
    try:
        ranks = Ranks.from_environment()
    except ValueError as err:
        raise PipelineError(f"torchrun's environment: {err}") from None
    device = configure_torch(rank_device(ranks, args.device), args.seed, args.threads,
                             deterministic=args.deterministic, tf32=args.tf32, cuda_graph=args.cuda_graph)
    with data_parallel.process_group(ranks, device, graphed=args.cuda_graph):
        train(args, sampling, checkpoint, device, ranks)


def train(args: argparse.Namespace, sampling: SampleSettings, checkpoint: Path, device: torch.device,
          ranks: Ranks) -> None:
    """Load, build, fit and (rank 0) write model.pt and train.h5, as `main` checked the arguments."""
    quiet = args.quiet or not ranks.main
    stream, n_bytes = streams_frames(args.dataset, args.device_cache_gb, device)
    data = load_dataset(args.dataset, frames=not stream)
    task = task_of(data.task, args.dataset)
    features = {"inputs": args.inputs, "input_frame": args.input_frame, "output_frame": args.output_frame,
                "frame_tangent": args.frame_tangent}
    built = task.build(NetworkRequest(args.arch, args.conv, args.pool, args.width, features,
                                      "--inputs/--input-frame/--output-frame/--frame-tangent"),
                       data, args.operators, args.dataset)
    spec, model, mesh = built.spec, built.model, built.mesh
    if stream and reads_previous_output(model):
        raise PipelineError(f"{args.dataset}: a network that reads its previous output is trained on the true "
                            f"displacements of every frame, which a streamed dataset does not hold: give "
                            f"--device-cache-gb room for {n_bytes / 2 ** 30:.1f} GiB")
    parameter_count = model.net.parameter_count()
    trained = trained_frames(data, args.train_on, args.dataset)
    if args.train_frames is not None:
        every = len(trained)
        trained = sequences_within(data, trained, args.train_frames, args.seed)
        args.epochs, sampling = same_steps(every, len(trained), args.epochs, sampling)
        if not quiet:
            print(f"train: {len(trained):,} of {every:,} frames (--train-frames {args.train_frames}), {args.epochs} "
                  f"epochs at a sample share of {sampling.share:g}: the steps of every frame", file=sys.stderr)
    reader = FrameReader(args.dataset) if stream else None
    try:
        frames = (task.streamed_frames(data, reader, split_batch_size(args.batch_size), device, args.sample_buffer)
                  if stream else task.frames(data, device))
        if stream and not quiet:
            print(f"train: {n_bytes / 2 ** 30:.2f} GiB of frames streamed from {args.dataset} (more than "
                  f"--device-cache-gb or half the free memory)", file=sys.stderr)
        train_ids = torch.as_tensor(trained, device=device)
        model = model.to(device)
        store, targets = frames.all_frames()
        model.normalise(store, train_ids, targets)
        settings = TrainSettings(args.epochs, args.batch_size, args.lr,
                                 LossWeights(args.loss_l1, args.loss_l2, args.loss_normal), args.seed,
                                 args.cuda_graph, args.input_noise, args.lr_schedule, sampling)
        resume_from = read_checkpoint(checkpoint)
        steps_per_epoch = data_parallel.steps_of(Sampler(len(trained), sampling).frames_per_epoch, args.batch_size,
                                                 ranks)
        start = time.perf_counter()
        with training_bar("train", args.epochs, steps_per_epoch, quiet) as bar:
            on_batch = batch_reporter(bar, args.epochs, steps_per_epoch)
            identity = {"dataset": data.fingerprint, "operators": mesh.fingerprint(),
                        "spec": dataclasses.asdict(spec), "features": dataclasses.asdict(model.spec),
                        "train_on": args.train_on, "train_frames": args.train_frames}
            try:
                history = fit(model, mesh.to(device), frames, train_ids, torch.as_tensor(data.test, device=device),
                              settings, resume_from, lambda state: write_checkpoint(checkpoint, state), identity,
                              on_batch, lambda notice: not ranks.main or bar.write(f"{checkpoint}: {notice}"),
                              ranks)
            except CheckpointError as err:
                raise PipelineError(f"{checkpoint}: {err}") from None
            except Diverged as err:
                raise PipelineError(f"{args.model}: {err} (--lr {args.lr:g})") from None
        seconds = time.perf_counter() - start
    finally:
        if reader is not None:
            reader.close()
    if not ranks.main:
        return      # rank 0 writes what every rank trained
    config = {**vars(args), "parameter_count": parameter_count}
    training = {"epochs": args.epochs, "batch_size": args.batch_size, "ranks": ranks.size, "lr": args.lr,
                "lr_schedule": args.lr_schedule,
                "seed": args.seed, "deterministic": args.deterministic, "tf32": args.tf32, "cuda_graph": args.cuda_graph,
                "input_noise": args.input_noise, "sampling": dataclasses.asdict(sampling),
                "streamed": stream, "train_on": args.train_on, "train_frames": len(trained),
                "sequences": trained_sequences(args.dataset, data, trained),
                "device": str(device), "loss_weights": dataclasses.asdict(settings.weights),
                "final_train_loss": history.train["total"][-1], "final_test_loss": history.test["total"][-1],
                "dataset": args.dataset, "dataset_fingerprint": data.fingerprint}
    save_model(Path(args.model), model.cpu(), spec, mesh, {"training": training})
    try:
        write_train_log(args.log, history, config, str(device), parameter_count, seconds)
    except BaseException:
        Path(args.model).unlink(missing_ok=True)      # the two outputs come as a pair, or not at all
        raise
    checkpoint.unlink(missing_ok=True)


if __name__ == "__main__":
    cli.run(main)
