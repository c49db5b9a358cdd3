"""Training throughput: samples (frames) per second of the upsampling network's optimiser steps on a real dataset,
per input variant and batch size, with the input features computed per batch (what `pipeline.train` does) and,
as the ceiling, precomputed once (the features do not depend on the weights).

    python bench/train_throughput.py DATASET.h5 OPERATORS.h5 [--device cpu|cuda] [--batch-sizes 3,16]
        [--variants positions,body_relative] [--conv RC9] [--width 0.25] [--steps 30] [--warmup 5] [--threads N]

Median seconds per step over `--steps` steps after `--warmup` (synchronised on CUDA), as samples/s; the ratio
column is against the positions variant at the same batch size in the same run. Also prints what the dataset
occupies on the device (inputs + targets): the whole of it stays there during training.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.losses import LossWeights, total_loss
from model.networks import NetworkSpec, build_network
from pipeline.artifacts.dataset import load_dataset
from pipeline.artifacts.operators import load_hierarchy
from pipeline.torch_setup import frames_on

ARCH = "D62 D124 D248 D D248 D_3 D248"
VARIANTS = {"positions": FeatureSpec(("position",)),
            "body_relative": FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")}


def seconds_per_step(model, mesh, frames, ids, batch_size, precomputed, steps, warmup) -> float:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    sync = torch.cuda.synchronize if ids.is_cuda else (lambda: None)
    cache = None
    if precomputed:
        with torch.no_grad():
            cache = [model.encode(frames.store.batch(ids[i:i + batch_size]))
                     for i in range(0, batch_size * (steps + warmup), batch_size)]
    times = []
    for step in range(warmup + steps):
        batch = ids[step * batch_size:(step + 1) * batch_size]
        sync()
        start = time.perf_counter()
        inputs = frames.store.batch(batch)
        displacement = (model.decode(*cache[step], mesh) if precomputed else model(inputs, mesh))
        loss, _ = total_loss(inputs.positions + displacement, inputs.positions + frames.targets[batch],
                             frames.faces, LossWeights())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        sync()
        if step >= warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset"), parser.add_argument("operators")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch-sizes", default="3,16")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--conv", default="RC9")
    parser.add_argument("--width", type=float, default=0.25)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    device = torch.device(args.device)
    data = load_dataset(args.dataset)
    frames = frames_on(data, device)
    gib = (frames.store.positions.nbytes + frames.targets.nbytes) / 2 ** 30
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu, {torch.get_num_threads()} threads"
    print(f"{where}; {len(data.inputs)} frames of {data.inputs.shape[1]} vertices on the device ({gib:.2f} GiB); "
          f"{ARCH} {args.conv} x{args.width:g}; median of {args.steps} steps after {args.warmup}")
    print("| variant | batch | features | samples/s | ms/step | x positions |\n|---|---|---|---|---|---|")
    baseline = {}
    for batch_size in map(int, args.batch_sizes.split(",")):
        ids = torch.randperm(len(data.train), generator=torch.Generator().manual_seed(0))
        ids = torch.as_tensor(data.train, device=device)[ids.to(device)]
        ids = ids.repeat(-(-batch_size * (args.steps + args.warmup) // len(ids)))
        for name in args.variants.split(","):
            spec = VARIANTS[name]
            net = build_network(NetworkSpec(ARCH, args.conv, "max", args.width, spec.channels))
            mesh = load_hierarchy(args.operators, args.conv, net.n_levels, data.faces).to(device)
            model = FeatureRegressor(net, spec, data.faces, data.rest_vertices).to(device)
            model.normalise(frames.store, ids[:64], frames.targets)
            for precomputed in (False, True):
                seconds = seconds_per_step(model, mesh, frames, ids, batch_size, precomputed, args.steps, args.warmup)
                rate = batch_size / seconds
                baseline.setdefault((batch_size, precomputed), rate)
                print(f"| {name} | {batch_size} | {'precomputed' if precomputed else 'per batch'} | {rate:.1f} | "
                      f"{seconds * 1e3:.1f} | {rate / baseline[(batch_size, precomputed)]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
