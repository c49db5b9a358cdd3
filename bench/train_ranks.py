"""Training throughput against the number of GPUs: the train stage itself (`pipeline.train` under torchrun,
DistributedDataParallel over NCCL, model/data_parallel.py) on a scene's real dataset and settings, one run per
GPU count, each rank at the settings' batch size (N GPUs train N x batch_size frames a step).

    python bench/train_ranks.py SETTINGS.json DATASET.h5 OPERATORS.h5 [--gpus 1,2,4] [--epochs 3]
        [--sample-share S] [--out DIR]

e.g. for the paper-profile pants after `snakemake --cores 16 --config profile=paper device=cuda:0 --
results/pants/dataset.h5 results/pants/operators.h5 results/pants/settings.json`:

    python bench/train_ranks.py results/pants/settings.json results/pants/dataset.h5 results/pants/operators.h5

Samples/s is the frames an epoch trains on over the epoch's wall time (train.h5 `epoch/seconds`: the steps and
the per-epoch scoring of the monitored test frames, which the ranks share too; not the start, the loading or
the normalisation), the median over the epochs after the first (which captures the CUDA graphs and warms
the allocator); each run starts from the same seed. The ratio column is against the first GPU count listed.
Every run goes through torchrun, one GPU count too, so that all pay the same launcher. --epochs and
--sample-share (default: the settings') size the runs; nothing else of the settings changes.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

from model.sampler import Sampler, SampleSettings
from pipeline.core.h5 import config_of


def run(gpus: int, settings: Path, dataset: Path, operators: Path, folder: Path, epochs: int,
        share: float | None) -> tuple[float, int, int]:
    """One training on `gpus` GPUs: its median samples/s over the epochs after the first, the frames an epoch
    trains on, and the batch size of each rank."""
    model, log = folder / f"model_{gpus}.pt", folder / f"train_{gpus}.h5"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={gpus}",
               "-m", "pipeline.train", str(dataset), str(operators), str(model), str(log), "--settings",
               str(settings), "--epochs", str(epochs), "--quiet", *(["--sample-share", str(share)] if share else [])]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"error: {gpus} GPU(s): the training failed:\n{done.stdout[-2000:]}{done.stderr[-4000:]}")
    with h5py.File(log) as f:
        seconds = f["epoch/seconds"][()]
        config = config_of(f)
    from torch import load        # after the runs: this process holds no GPU while they train
    training = load(model, weights_only=True)["training"]
    per_epoch = Sampler(training["train_frames"], SampleSettings(**training["sampling"])).frames_per_epoch
    return per_epoch / statistics.median(seconds[1:]), per_epoch, config["batch_size"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("settings", type=Path), parser.add_argument("dataset", type=Path)
    parser.add_argument("operators", type=Path)
    parser.add_argument("--gpus", default="1,2,4", help="GPU counts, comma-separated")
    parser.add_argument("--epochs", type=int, default=3, help="per run; the first is not timed (at least 2)")
    parser.add_argument("--sample-share", type=float, help="share of the training frames an epoch visits "
                                                           "(default: the settings')")
    parser.add_argument("--out", type=Path, help="keep each run's model.pt and train.h5 here (default: dropped)")
    args = parser.parse_args()
    counts = [int(n) for n in args.gpus.split(",")]
    if args.epochs < 2 or min(counts) < 1:
        parser.error("--epochs must be at least 2 and every GPU count at least 1")
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.out or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        results = {n: run(n, args.settings, args.dataset, args.operators, folder, args.epochs, args.sample_share)
                   for n in counts}
    import torch
    name = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu (gloo)"
    first = counts[0]
    print(f"{name}; {args.dataset}: {results[first][1]:,} frames an epoch, batch {results[first][2]} a rank; "
          f"median epoch after the first of {args.epochs}")
    print(f"| GPUs | samples/s | x {first} GPU{'s' if first > 1 else ''} | per GPU |\n|---|---|---|---|")
    for n, (rate, _, _) in results.items():
        ratio = rate / results[first][0]
        print(f"| {n} | {rate:,.1f} | {ratio:.2f}x | {ratio * first / n:.0%} |")


if __name__ == "__main__":
    main()
