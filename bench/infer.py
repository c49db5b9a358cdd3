"""Upsampling inference speed: ms per frame for the paper's four Table 3 network sizes, next to the paper's figures.

For each mesh (the flag cloth of bench/cloth_solver.py's cases, Loop-subdivided twice, operators built by meshops) and each
size (RC13, RC9, RC9 x/2, RC9 x/4 of D62 D124 D248 D D248 D_3 D248), times one frame: the network alone, and Loop
subdivision S x_low (a padded-stencil gather on the device) + the network, as the paper's "DL + SubD" column.
Median over repeats after warm-up, for each mode: eager, or CUDA-graph replay ("graph"), each optionally with TF32
matmuls ("-tf32"). Usage:
  python bench/infer.py [--device cpu|cuda] [--cases flag-cpu,15k] [--sizes RC13,RC9,RC9x/2,RC9x/4]
      [--modes eager,graph,eager-tf32,graph-tf32] [--repeats 20] [--warmup 5] [--threads N] [--out table.md]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from geometry.loop_subdivision import loop_subdivide
from meshops import build_operators
from model.mesh_hierarchy import mesh_hierarchy
from model.networks import NetworkSpec, build_network
from scenes.flag_mesh import flag_cloth

ARCH = "D62 D124 D248 D D248 D_3 D248"
# Low-res grid edge lengths, as bench/cloth_solver.py: the CPU-profile flag, the paper-sized flag, a ~15k-vertex high-res.
CASES = {"flag-cpu": 0.12, "flag": 0.08, "15k": 0.046}
SIZES = {"RC13": ("RC13", 1.0), "RC9": ("RC9", 1.0), "RC9x/2": ("RC9", 0.5), "RC9x/4": ("RC9", 0.25)}
# Paper Table 3, "DL + SubD" ms on an RTX 2080 Ti, by high-res vertex count.
PAPER_MS = {4063: {"RC13": 9.4, "RC9": 5.7, "RC9x/2": 3.7, "RC9x/4": 2.2},
            8654: {"RC13": 17.6, "RC9": 10.2, "RC9x/2": 5.9, "RC9x/4": 3.4},
            14634: {"RC13": 26.6, "RC9": 15.2, "RC9x/2": 9.1, "RC9x/4": 5.1}}


def build_case(max_edge: float, convs: list[str], levels: int):
    low, low_faces = flag_cloth(max_edge)
    subdivision, faces = loop_subdivide(low, low_faces, levels=2)
    start = time.perf_counter()
    hierarchy = build_operators(subdivision @ low, faces, conv=convs, pooling_steps=levels - 1)
    seconds = time.perf_counter() - start
    meshes = {name: mesh_hierarchy([lv.conv[name] for lv in hierarchy],
                                   [lv.coarsening.pool for lv in hierarchy[:-1]],
                                   [lv.coarsening.unpool for lv in hierarchy[:-1]]) for name in convs}
    return low, subdivision, meshes, seconds


def stencil_matmul(matrix, device: torch.device):
    """x -> matrix @ x for a sparse matrix with few entries per row, as one gather and a weighted sum (padded
    rows, like the mesh convolution): graph-capturable and deterministic, unlike a cuSPARSE call."""
    csr = matrix.tocsr()
    counts = np.diff(csr.indptr)
    width = int(counts.max())
    slots = np.arange(width)[None, :] < counts[:, None]
    columns = np.zeros(slots.shape, dtype=np.int64)
    weights = np.zeros(slots.shape, dtype=np.float32)
    columns[slots], weights[slots] = csr.indices, csr.data
    columns_t = torch.as_tensor(columns, device=device)
    weights_t = torch.as_tensor(weights, device=device)[..., None]
    return lambda x: (x[columns_t] * weights_t).sum(dim=1)


def timed(fn, repeats: int, warmup: int, device: torch.device) -> float:
    """Median ms of `fn()` over `repeats` calls after `warmup` calls, synchronised on CUDA."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        sync()
        start = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def as_graph(fn, device: torch.device, warmup: int):
    """Capture `fn` (static inputs and outputs) as a CUDA graph; returns its replay."""
    stream = torch.cuda.Stream(device)
    stream.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(stream):
        for _ in range(max(warmup, 3)):
            fn()
    torch.cuda.current_stream(device).wait_stream(stream)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        fn()
    return graph.replay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--cases", default="flag-cpu,15k", help=f"comma-separated of {', '.join(CASES)}")
    parser.add_argument("--sizes", default=",".join(SIZES), help=f"comma-separated of {', '.join(SIZES)}")
    parser.add_argument("--modes", default="eager", help="comma-separated of eager, graph, eager-tf32, graph-tf32")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--out", help="also write the table (markdown) here")
    args = parser.parse_args()
    device = torch.device(args.device)
    modes = args.modes.split(",")
    if device.type == "cuda" and not torch.cuda.is_available():
        sys.exit(f"error: device '{args.device}' requested but torch finds no CUDA device")
    if any(m not in ("eager", "graph", "eager-tf32", "graph-tf32") for m in modes) or \
            (device.type != "cuda" and modes != ["eager"]):
        sys.exit(f"error: --modes {args.modes}: graph and tf32 modes need a CUDA device")
    torch.set_flush_denormal(True)
    if args.threads:
        torch.set_num_threads(args.threads)
    sizes = args.sizes.split(",")
    convs = sorted({SIZES[s][0] for s in sizes})
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    header = ("| mesh | high-res V | size | params | " + " | ".join(f"net ms {m} | SubD+net ms {m}" for m in modes)
              + " | paper DL+SubD ms (hv) |\n|" + "---|" * (5 + 2 * len(modes)))
    title = f"device: {where}; median of {args.repeats} after {args.warmup} warm-up; torch {torch.__version__}"
    print(f"{title}\n{header}", flush=True)
    rows = []
    for case in args.cases.split(","):
        low, subdivision, meshes, build_seconds = build_case(CASES[case], convs, levels=9)
        n_high = subdivision.shape[0]
        print(f"<!-- {case}: operators for {n_high} vertices built in {build_seconds:.1f} s -->", flush=True)
        subdivide = stencil_matmul(subdivision, device)
        x_low = torch.as_tensor(low, dtype=torch.float32, device=device)
        paper_hv = min(PAPER_MS, key=lambda hv: abs(hv - n_high))
        for size in sizes:
            conv, width = SIZES[size]
            net = build_network(NetworkSpec(ARCH, conv, "max", width))
            model = net.to(device).eval()     # the mesh CNN alone: the input features are not timed here
            mesh = meshes[conv].to(device)
            x_high = subdivide(x_low)[None]
            fns = {"net": lambda: model(x_high, mesh), "full": lambda: model(subdivide(x_low)[None], mesh)}
            cells = []
            for mode in modes:
                torch.backends.cuda.matmul.allow_tf32 = mode.endswith("tf32")
                with torch.no_grad():
                    for fn in fns.values():
                        run = as_graph(fn, device, args.warmup) if mode.startswith("graph") else fn
                        cells.append(f"{timed(run, args.repeats, args.warmup, device):.2f}")
            row = (f"| {case} | {n_high} | {size} | {net.parameter_count():,} | " + " | ".join(cells)
                   + f" | {PAPER_MS[paper_hv][size]} ({paper_hv}) |")
            rows.append(row)
            print(row, flush=True)
    if args.out:
        Path(args.out).write_text(f"{title}\n\n{header}\n" + "\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
