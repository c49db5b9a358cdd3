"""Dataset stage speed: wall seconds of `python -m pipeline.dataset` (upsampling, torso frame) over N synthetic
sequences of the paper-profile pants (757 low-res, 11,719 high-res vertices), at each --threads, and a reference
checkout of the stage (the code before a change) beside them in the same run.

Each sequence folder holds its real scene.h5 (the mannequin's motion, capsules and torso frames) and made-up runs
(the rest mesh waving, high-res wrinkles on S x_low: no simulation), written as the simulate stage writes them, to
DIR (default: a temporary folder; inputs already there are reused). The last sequence is the held-out one. A row's
time is the whole command as Snakemake runs it, interpreter start and imports included: the median of --repeat
runs after one warm-up run (which also fills the page cache with the inputs), the variants' runs interleaved so
that a change in the machine's load falls on all of them; beside it the run's CPU seconds (user + system, all
threads), which a busy machine inflates less. The ratio is against the first row (the reference where one is
given). Every variant must write the same dataset, each array and attribute: the bench stops otherwise.
Usage:
  python bench/dataset_stage.py [--sequences 12] [--frames 400] [--threads 1,2] [--repeat 3]
      [--reference CHECKOUT] [--dir DIR]
e.g. against the last commit: git archive HEAD | tar -x -C /tmp/before; python bench/dataset_stage.py --reference
/tmp/before
"""
from __future__ import annotations

import argparse
import hashlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import yaml

from geometry.loop_subdivision import loop_subdivide
from pipeline.artifacts.scene import write_scene
from pipeline.core.config import resolve_scene
from pipeline.core.h5 import atomic_h5, write_csr
from scenes.registry import build_scene

REPO = Path(__file__).resolve().parents[1]


def write_inputs(root: Path, n_sequences: int, n_frames: int) -> list[Path]:
    """root/subdiv.h5 and the sequence folders (made unless there); returns the folders, in dataset order."""
    settings = resolve_scene(yaml.safe_load((REPO / "workflow_config.yaml").read_text()), "pants", "paper")
    settings.update(frames=n_frames)
    names = [f"train_{k:03d}" for k in range(n_sequences - 1)] + ["held_out_000"]
    folders = [root / f"{n_frames}" / name for name in names]
    if all((folder / "sim_high.h5").is_file() for folder in folders):
        return folders
    rest = build_scene(settings, names[0]).rest
    S, high_faces = loop_subdivide(rest.vertices, rest.faces, 2)
    with atomic_h5(root / "subdiv.h5", "subdivide") as out:
        write_csr(out, "S", S)
        out["vertices"], out["faces"] = S @ rest.vertices, high_faces.astype(np.int32)
    for k, (name, folder) in enumerate(zip(names, folders)):
        scene = build_scene(settings, name)
        folder.mkdir(parents=True, exist_ok=True)
        write_scene(folder / "scene.h5", scene, settings)
        t = np.arange(scene.n_frames)[:, None, None] + 100 * k
        low = rest.vertices + 0.01 * np.sin(0.3 * t + rest.vertices[None, :, :1] * 5)
        smooth = (S @ low.transpose(1, 0, 2).reshape(len(rest.vertices), -1)).reshape(S.shape[0], -1, 3)
        high = smooth.transpose(1, 0, 2) + 0.002 * np.cos(0.2 * t)
        for level, positions, faces in (("low", low, rest.faces), ("high", high, high_faces)):
            with atomic_h5(folder / f"sim_{level}.h5", f"simulate_{level}", settings) as out:
                out["positions"], out["faces"] = positions.astype(np.float32), faces.astype(np.int32)
    return folders


def content_digest(path: Path) -> str:
    """SHA-256 of every dataset's values and every attribute of an HDF5 file, by name: what 'the same dataset'
    means here (the file's bytes also hold where HDF5 put each object)."""
    digest = hashlib.sha256()

    def add(name: str, obj) -> None:
        digest.update(name.encode())
        for key in sorted(obj.attrs):
            digest.update(key.encode() + np.asarray(obj.attrs[key]).tobytes())
        if isinstance(obj, h5py.Dataset):
            digest.update(str((obj.dtype, obj.shape, obj.chunks)).encode() + obj[()].tobytes())

    with h5py.File(path, "r") as f:
        add("/", f)
        f.visititems(add)
    return digest.hexdigest()


def run_stage(checkout: Path, subdiv: Path, out: Path, folders: list[Path], threads: int | None) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one run of the stage of `checkout` (threads None: a reference
    without --threads)."""
    command = [sys.executable, "-m", "pipeline.dataset", str(subdiv), str(out), *map(str, folders),
               "--frame", "torso", "--quiet", *([] if threads is None else ["--threads", str(threads)])]
    cpu, start = _children_cpu(), time.perf_counter()
    subprocess.run(command, cwd=checkout, check=True)
    return time.perf_counter() - start, _children_cpu() - cpu


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=12)
    parser.add_argument("--frames", type=int, default=400,
                        help="frames per sequence, the settle period's 100 included (kept by the first only)")
    parser.add_argument("--threads", default="1,2", help="comma-separated --threads of this checkout's stage")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--reference", type=Path, help="a checkout of the stage to compare with (run as it is)")
    parser.add_argument("--dir", type=Path, help="where the inputs and outputs go (default: a temporary folder)")
    args = parser.parse_args()
    scratch = None if args.dir else tempfile.TemporaryDirectory()
    root = args.dir or Path(scratch.name)
    folders = write_inputs(root, args.sequences, args.frames)
    variants = ([("reference", args.reference, None)] if args.reference else []) + \
               [(f"--threads {t}", REPO, int(t)) for t in args.threads.split(",")]
    times: dict[str, list[tuple[float, float]]] = {name: [] for name, _, _ in variants}
    digests = {}
    for repeat in range(args.repeat + 1):          # the first round is the warm-up
        for name, checkout, threads in variants:
            out = root / "dataset.h5"
            seconds = run_stage(checkout, root / "subdiv.h5", out, folders, threads)
            if repeat:
                times[name].append(seconds)
            else:
                digests[name] = content_digest(out)
                with h5py.File(out, "r") as f:
                    kept = int(f.attrs["n_frames"])
            out.unlink()
    if len(set(digests.values())) != 1:
        sys.exit(f"the variants wrote different datasets: {digests}")
    print(f"{args.sequences} sequences of {args.frames} frames, {kept} kept (757 -> 11,719 vertices, torso frame); "
          f"median of {args.repeat} runs after 1 warm-up; every variant wrote the same dataset")
    print("| variant | wall s | CPU s | frames/s | x first row (wall) |\n|---|---|---|---|---|")
    first = statistics.median(wall for wall, _ in times[variants[0][0]])
    for name, _, _ in variants:
        seconds, cpu = (statistics.median(column) for column in zip(*times[name]))
        print(f"| {name} | {seconds:.2f} | {cpu:.2f} | {kept / seconds:.0f} | {first / seconds:.2f} |")
    if scratch is not None:
        scratch.cleanup()


if __name__ == "__main__":
    main()
