"""Training throughput with the dataset resident on the device against streamed from disk (model.streaming), at
10k, 100k and 500k frames of a synthetic upsampling dataset: samples (frames) per second of the optimiser steps.

    python bench/train_stream.py [--frames 10000,100000,500000] [--vertices 441] [--device cpu|cuda]
        [--batch-size 3] [--share 0.1] [--block 32] [--buffer 4096] [--steps 30] [--warmup 10] [--dir DIR]
        [--threads N]

The dataset is a waving sheet (a square grid Loop-subdivided twice to about --vertices vertices), written by the
dataset stage's own writer in sequences of 1,000 frames to DIR (default: a temporary folder; an existing file of
the same size is reused), with operators built by the operators stage. Each row trains the same small network
(bench/train_throughput.py's step and timing: median seconds per step over --steps after --warmup, synchronised
on CUDA) on an epoch order the sampler draws (--share of the frames in blocks of --block, shuffled --buffer at a
time), once with every frame on the device and once streamed: a step's time includes waiting for the loader. The
resident row is skipped where the frames do not fit half the free memory, as `pipeline.train` would stream them.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch
from train_throughput import seconds_per_step

from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.networks import NetworkSpec, build_network
from model.sampler import Sampler, SampleSettings
from pipeline import operators
from pipeline.artifacts.dataset import DatasetLayout, FrameReader, SequenceFrames, Split, load_dataset, write_dataset
from pipeline.artifacts.operators import load_hierarchy
from pipeline.core import cli
from pipeline.core.h5 import atomic_h5, write_csr
from pipeline.core.torch_setup import configure_torch, keep_resident
from pipeline.tasks.upsampling import UpsamplingTask

ARCH, CONV, LEVELS = "D16 D32 D D32", "RC7", 4
FEATURES = FeatureSpec(("position", "velocity"))
SEQUENCE_FRAMES = 1000


def write_sheet(folder: Path, vertices: int, n_frames: int) -> Path:
    """folder/dataset_<n_frames>.h5 (made unless there) and folder/operators.h5 of a sheet of about `vertices`
    high-res vertices waving in sequences of SEQUENCE_FRAMES frames."""
    n = max(2, round((vertices ** 0.5 - 1) / 4) + 1)      # n x n grid: (4 (n - 1) + 1)^2 vertices twice subdivided
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    low_rest = np.stack([c.ravel() / (n - 1), np.zeros(n * n), r.ravel() / (n - 1)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, d, e = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    low_faces = np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])
    S, faces = loop_subdivide(low_rest, low_faces, 2)
    rest = S @ low_rest
    if not (folder / "operators.h5").is_file():
        with atomic_h5(folder / "subdiv.h5", "subdivide") as f:
            write_csr(f, "S", S)
            f["vertices"], f["faces"] = rest, faces.astype(np.int32)
        cli.run(operators.main, [str(folder / "subdiv.h5"), str(folder / "operators.h5"), "--conv", CONV,
                                 "--levels", str(LEVELS), "--quiet"])
    path = folder / f"dataset_{n_frames}.h5"
    if path.is_file():
        return path
    sequence = np.arange(n_frames) // SEQUENCE_FRAMES
    test = np.arange(0, n_frames, 10)
    layout = DatasetLayout(faces, rest, low_faces, len(low_rest), sequence, np.arange(n_frames) % SEQUENCE_FRAMES,
                           tuple(f"train_{k:03d}" for k in range(sequence[-1] + 1)), ("train",) * (sequence[-1] + 1),
                           ("",) * (sequence[-1] + 1), Split(np.setdiff1d(np.arange(n_frames), test), test,
                                                             np.zeros(0, np.int64), ()),
                           "world", 0, 0.1, 1 / 60, subdivision=S)

    def sequences():
        for first in range(0, n_frames, SEQUENCE_FRAMES):
            t = np.arange(first, min(first + SEQUENCE_FRAMES, n_frames))[:, None]
            low = np.repeat(low_rest[None], len(t), axis=0)
            low[:, :, 1] = 0.1 * np.sin(3 * low_rest[:, 0] + 0.05 * t + 0.01 * first) * low_rest[:, 2]
            smooth = np.einsum("hl,flc->fhc", S.toarray(), low) if len(rest) < 2000 else np.stack([S @ x for x in low])
            targets = 0.01 * np.sin(12 * smooth[:, :, :1] + 0.3 * t[..., None]) * [0.0, 1.0, 0.0]
            yield SequenceFrames(None, targets.astype(np.float32), low.astype(np.float32),
                                 np.tile(np.float32([0, -1, 0]), (len(t), 1)), None, None)
    write_dataset(path, {}, layout, sequences(), None)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="10000,100000,500000")
    parser.add_argument("--vertices", type=int, default=441, help="about this many high-res vertices")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch-size", type=int, default=3)
    parser.add_argument("--share", type=float, default=0.1)
    parser.add_argument("--block", type=int, default=32)
    parser.add_argument("--buffer", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--dir", help="where the datasets are written (default: a temporary folder)")
    parser.add_argument("--threads", type=int)
    args = parser.parse_args()
    device = configure_torch(args.device, 0, args.threads)
    scratch = None if args.dir else tempfile.TemporaryDirectory()
    folder = Path(args.dir or scratch.name)
    folder.mkdir(parents=True, exist_ok=True)
    task = UpsamplingTask()
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu, {torch.get_num_threads()} threads"
    print(f"{where}; {ARCH} {CONV}, inputs {', '.join(FEATURES.inputs)}; batch {args.batch_size}; epoch order: "
          f"share {args.share:g} in blocks of {args.block}, shuffled {args.buffer} at a time; median of "
          f"{args.steps} steps after {args.warmup}")
    print("| frames | mesh (low / high vertices) | on disk (GiB) | mode | samples/s | ms/step | x resident |\n"
          "|---|---|---|---|---|---|---|")
    for n_frames in map(int, args.frames.split(",")):
        path = write_sheet(folder, args.vertices, n_frames)
        data = load_dataset(path, frames=False)
        gib = path.stat().st_size / 2 ** 30
        mesh_size = f"{data.subdivision.shape[1]} / {len(data.rest_vertices)}"
        train = torch.as_tensor(data.train, device=device)
        order = train[Sampler(len(train), SampleSettings(args.share, args.block, args.buffer))
                      .epoch(torch.Generator().manual_seed(0)).to(device)]
        needed = args.batch_size * (args.steps + args.warmup)
        order = order.repeat(-(-needed // len(order)))[:needed]
        resident_rate = None
        for mode in ("resident", "streamed"):
            if mode == "resident" and not keep_resident(path.stat().st_size, None, device):
                print(f"| {n_frames:,} | {mesh_size} | {gib:.2f} | resident | skipped: more than half the free "
                      f"memory | | |", flush=True)
                continue
            reader = FrameReader(path) if mode == "streamed" else None
            frames = (task.streamed_frames(data, reader, args.batch_size, device, args.buffer) if reader
                      else task.frames(load_dataset(path), device))
            torch.manual_seed(0)
            net = build_network(NetworkSpec(ARCH, CONV, "max", 1.0, FEATURES.channels))
            mesh = load_hierarchy(folder / "operators.h5", CONV, net.n_levels, data.faces).to(device)
            model = FeatureRegressor(net, FEATURES, data.faces, data.rest_vertices).to(device)
            store, targets = frames.all_frames()
            model.normalise(store, order[:64], targets)
            seconds = seconds_per_step(model, mesh, frames, order, args.batch_size, "eager", args.steps,
                                       args.warmup)
            if reader is not None:
                reader.close()
            rate = args.batch_size / seconds
            resident_rate = resident_rate or (rate if mode == "resident" else None)
            ratio = f"{rate / resident_rate:.2f}" if resident_rate else "–"
            print(f"| {n_frames:,} | {mesh_size} | {gib:.2f} | {mode} | {rate:.1f} | {seconds * 1e3:.1f} | {ratio} |",
                  flush=True)
            del frames
    if scratch is not None:
        scratch.cleanup()


if __name__ == "__main__":
    main()
