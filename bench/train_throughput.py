"""Training throughput: samples (frames) per second of the upsampling network's optimiser steps on a real dataset,
per input variant, batch size and mode, through the training loop's own step (model.training_step):

  eager        what `pipeline.train` does by default: input features computed per batch, then the step;
  graph        the same step replayed as one CUDA graph (training.cuda_graph; CUDA only);
  precomputed  the ceiling of caching the features (they do not depend on the weights): the step without them;
  precomputed-graph  both.

    python bench/train_throughput.py DATASET.h5 OPERATORS.h5 [--device cpu|cuda] [--batch-sizes 3,16]
        [--variants positions,body_relative] [--modes eager,graph] [--conv RC9] [--width 0.25] [--steps 30]
        [--warmup 5] [--threads N] [--arithmetic deterministic,atomic,tf32,atomic-tf32]

Torch is set up as the training stage sets it up (deterministic, seeded). Median seconds per step over `--steps`
steps after `--warmup` (synchronised on CUDA; a graph mode captures during its warm-up), as samples/s; the ratio
column is against the eager mode of the same variant and batch size in the same run, with the first `--arithmetic`
listed (pipeline.core.torch_setup.set_arithmetic: the training's `deterministic` and `tf32` keys; CUDA only). Also
prints what the dataset occupies on the device (x_low + targets): the whole of it stays there during training
(bench/train_stream.py measures a dataset streamed from disk instead).
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.losses import LossWeights, total_loss
from model.networks import NetworkSpec, build_network
from model.training import Frames, in_batches
from model.training_step import WARMUP_STEPS, GraphedStep, adam, eager_step
from pipeline.artifacts.dataset import load_dataset
from pipeline.artifacts.operators import load_hierarchy
from pipeline.core.torch_setup import configure_torch, set_arithmetic
from pipeline.tasks import frames_of

ARCH = "D62 D124 D248 D D248 D_3 D248"
VARIANTS = {"positions": FeatureSpec(("position",)),
            "body_relative": FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")}
MODES = ("eager", "graph", "precomputed", "precomputed-graph")
ARITHMETIC = {"deterministic": (True, False), "atomic": (False, False), "tf32": (True, True),
              "atomic-tf32": (False, True)}           # (training.deterministic, training.tf32)


class PrecomputedFeatures:
    """A Problem whose sample k is the k-th frame of `ids`, its network input encoded once beforehand."""

    def __init__(self, model: FeatureRegressor, frames: Frames, ids: torch.Tensor, chunk: int = 16):
        self.frames, self.ids = frames, ids
        with torch.no_grad():
            encoded = [model.encode(frames.store.batch(ids[i:i + chunk])) for i in range(0, len(ids), chunk)]
        self.inputs = torch.cat([x for x, _ in encoded])
        self.local = None if encoded[0][1] is None else torch.cat([f for _, f in encoded])

    def feed(self, slots: torch.Tensor, batch_size: int):
        return in_batches(slots, batch_size)

    def batch_loss(self, model, mesh, slots: torch.Tensor, weights: LossWeights):
        real = self.ids[slots]
        positions = self.frames.store.predictor(real)
        displacement = model.decode(self.inputs[slots], None if self.local is None else self.local[slots], mesh)
        return total_loss(positions + displacement, positions + self.frames.targets[real], self.frames.faces, weights)


def seconds_per_step(model, mesh, frames: Frames, ids: torch.Tensor, batch_size: int, mode: str, steps: int,
                     warmup: int) -> float:
    graphed = mode.endswith("graph")
    problem, samples = frames, ids
    if mode.startswith("precomputed"):
        problem, samples = PrecomputedFeatures(model, frames, ids), torch.arange(len(ids), device=ids.device)
    step = eager_step(model, mesh, problem, adam(model, 1e-3, graphed), LossWeights())
    if graphed:
        step = GraphedStep(step, batch_size, ids.device)
    sync = torch.cuda.synchronize if ids.is_cuda else (lambda: None)
    times = []
    # A step's time includes getting its batch from the problem (a streamed dataset's wait for its loader).
    batches = problem.feed(samples[:(warmup + steps) * batch_size], batch_size)
    for k in range(warmup + steps):
        sync()
        start = time.perf_counter()
        step(next(batches))
        sync()
        if k >= warmup:
            times.append(time.perf_counter() - start)
    batches.close()
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset"), parser.add_argument("operators")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch-sizes", default="3,16")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--modes", default="eager,precomputed", help=f"comma-separated of {', '.join(MODES)}")
    parser.add_argument("--conv", default="RC9")
    parser.add_argument("--width", type=float, default=0.25)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int)
    parser.add_argument("--arithmetic", default="deterministic", help=f"comma-separated of {', '.join(ARITHMETIC)}")
    args = parser.parse_args()
    modes, arithmetics = args.modes.split(","), args.arithmetic.split(",")
    if not set(modes) <= set(MODES):
        parser.error(f"--modes: one or more of {', '.join(MODES)}")
    if not set(arithmetics) <= set(ARITHMETIC):
        parser.error(f"--arithmetic: one or more of {', '.join(ARITHMETIC)}")
    if any(m.endswith("graph") for m in modes) and (args.device == "cpu" or args.warmup <= WARMUP_STEPS):
        parser.error(f"graph modes need a CUDA --device and --warmup > {WARMUP_STEPS} (capture happens in it)")
    device = configure_torch(args.device, 0, args.threads)
    data = load_dataset(args.dataset)
    frames = frames_of(data, device)
    gib = (frames.store.low.nbytes + frames.targets.nbytes) / 2 ** 30
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu, {torch.get_num_threads()} threads"
    print(f"{where}; {len(data.sequence)} frames of {len(data.rest_vertices)} vertices on the device ({gib:.2f} GiB); "
          f"{ARCH} {args.conv} x{args.width:g}; median of {args.steps} steps after {args.warmup}")
    print("| variant | batch | mode | arithmetic | samples/s | ms/step | x eager |\n|---|---|---|---|---|---|---|")
    for batch_size in map(int, args.batch_sizes.split(",")):
        ids = torch.randperm(len(data.train), generator=torch.Generator().manual_seed(0))
        ids = torch.as_tensor(data.train, device=device)[ids.to(device)]
        needed = batch_size * (args.steps + args.warmup)
        ids = ids.repeat(-(-needed // len(ids)))[:needed]
        for name in args.variants.split(","):
            spec = VARIANTS[name]
            if "body" in spec.inputs and data.context.capsule_a.shape[1] == 0:
                print(f"| {name} | {batch_size} | – | skipped: {args.dataset} has no body | | |")
                continue
            mesh = None
            eager_rate = None
            for mode, arithmetic in ((m, a) for m in modes for a in arithmetics):
                set_arithmetic(*ARITHMETIC[arithmetic])
                torch.manual_seed(0)
                net = build_network(NetworkSpec(ARCH, args.conv, "max", args.width, spec.channels))
                mesh = mesh or load_hierarchy(args.operators, args.conv, net.n_levels, data.faces).to(device)
                model = FeatureRegressor(net, spec, data.faces, data.rest_vertices).to(device)
                model.normalise(frames.store, ids[:64], frames.targets)
                seconds = seconds_per_step(model, mesh, frames, ids, batch_size, mode, args.steps, args.warmup)
                rate = batch_size / seconds
                eager_rate = eager_rate or (rate if mode == "eager" else None)
                ratio = f"{rate / eager_rate:.2f}" if eager_rate else "–"
                print(f"| {name} | {batch_size} | {mode} | {arithmetic} | {rate:.1f} | {seconds * 1e3:.1f} | {ratio} |",
                      flush=True)


if __name__ == "__main__":
    main()
