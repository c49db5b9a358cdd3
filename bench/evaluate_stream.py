"""The evaluate stage on a synthetic upsampling dataset with its frames resident against streamed from disk
(model.scoring, model.streaming): seconds and peak resident memory of the whole `python -m pipeline.evaluate`
process, at 2k and 20k frames by default.

    python bench/evaluate_stream.py [--frames 2000,20000] [--vertices 1000] [--repeats 3] [--device cpu|cuda]
        [--threads N] [--dir DIR] [--export-frames 1] [--no-predictions]

The datasets are bench/train_stream.py's waving sheet (the dataset stage's own writer, sequences of 1,000 frames,
every tenth frame a test frame) in DIR (default: a temporary folder; a file of the same size is reused); a small
network (train_stream's architecture) is trained once, one epoch on a share of the smallest dataset's frames.
Each row runs the stage in a fresh process, --device-cache-gb 1e6 (resident) or 0 (streamed), with no stills or
videos, one timed frame, --export-frames OBJ files and (unless --no-predictions) every frame's predicted positions
in eval.h5: the median wall time and peak RSS (the process's own, from wait4) of --repeats runs after one warm-up
run that is not counted. Wall time includes the interpreter's start and imports (~3 s on a 2-core machine).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
from train_stream import ARCH, CONV, write_sheet

MODES = {"resident": "1e6", "streamed": "0"}


def run_stage(args: list[str]) -> tuple[float, int]:
    """Wall seconds and peak RSS (bytes) of `python -m <args>` in its own process; its failure is this one's."""
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", *args])
    _, status, usage = os.wait4(process.pid, 0)      # this child's own usage (RUSAGE_CHILDREN: the largest child's)
    seconds = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)    # reaped here: Popen must not wait for it again
    if process.returncode:
        raise SystemExit(f"{args[0]} failed with exit status {process.returncode}")
    return seconds, usage.ru_maxrss * 1024          # Linux: kilobytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="2000,20000")
    parser.add_argument("--vertices", type=int, default=1000, help="about this many high-res vertices")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--export-frames", type=int, default=1, help="OBJ files written (0: every frame)")
    parser.add_argument("--no-predictions", action="store_true", help="eval.h5 without the predicted positions")
    parser.add_argument("--dir", help="where the datasets are written (default: a temporary folder)")
    args = parser.parse_args()
    scratch = None if args.dir else tempfile.TemporaryDirectory()
    folder = Path(args.dir or scratch.name)
    folder.mkdir(parents=True, exist_ok=True)
    counts = sorted(map(int, args.frames.split(",")))
    datasets = {n: write_sheet(folder, args.vertices, n) for n in counts}
    model = folder / "model.pt"
    if not model.is_file():       # one epoch on ~200 frames: the network's accuracy is not what is measured
        run_stage(["pipeline.train", str(datasets[counts[0]]), str(folder / "operators.h5"), str(model),
                   str(folder / "train.h5"), "--arch", ARCH, "--conv", CONV, "--inputs", "position,velocity",
                   "--epochs", "1", "--sample-share", f"{min(1.0, 200 / counts[0]):g}", "--device", args.device,
                   "--threads", str(args.threads), "--quiet"])
    flags = ["--render-frames", "0", "--video-frames", "0", "--export-frames", str(args.export_frames),
             "--timing-frames", "1", "--device", args.device, "--threads", str(args.threads), "--quiet",
             *(["--no-predictions"] if args.no_predictions else [])]
    print(f"{args.device}, {args.threads} threads; {ARCH} {CONV}, inputs position, velocity; --export-frames "
          f"{args.export_frames}, predictions {'not ' if args.no_predictions else ''}stored; median of "
          f"{args.repeats} runs after one warm-up")
    print("| frames | mesh (high vertices) | dataset (MiB) | mode | s | peak RSS (MiB) | eval.h5 (MiB) |\n"
          "|---|---|---|---|---|---|---|")
    for n in counts:
        for mode, budget in MODES.items():
            out = folder / f"eval_{n}_{mode}"
            stage = ["pipeline.evaluate", str(datasets[n]), str(folder / "operators.h5"), str(model),
                     str(out / "eval.h5"), str(out / "report.md"), "--device-cache-gb", budget, *flags]
            runs = [run_stage(stage) for _ in range(args.repeats + 1)][1:]
            seconds, peak = (float(np.median(values)) for values in zip(*runs))
            with h5py.File(datasets[n]) as f:
                vertices = f["target"].shape[1]
            print(f"| {n:,} | {vertices:,} | {datasets[n].stat().st_size / 2 ** 20:.0f} | {mode} | {seconds:.1f} | "
                  f"{peak / 2 ** 20:.0f} | {(out / 'eval.h5').stat().st_size / 2 ** 20:.0f} |", flush=True)
    if scratch is not None:
        scratch.cleanup()


if __name__ == "__main__":
    main()
