"""Upsampling inference speed: ms per call of the paper's four Table 3 network sizes, eager against the deployment
path (model/inference.py, deploy/), with ratios against eager measured in the same run.

For each mesh (the flag cloth of bench/cloth_solver.py's cases, Loop-subdivided twice, operators built by meshops),
each size (RC13, RC9, RC9 x/2, RC9 x/4 of D62 D124 D248 D D248 D_3 D248, random weights) and each mode, times:
  net    the mesh CNN alone on its input features (eager: model.networks; fast: model.inference.FastNetwork,
         reordered tables, normalisation folded, plain gather + matmul);
  SubD   Loop subdivision S x_low alone (a padded-stencil gather on the device);
  whole  the whole learned path of a frame: S x_low, input features, network, S x_low + displacement
         (the paper's "DL + SubD" column, plus the features).
Modes: eager, graph (eager replayed as one CUDA graph), eager-tf32, graph-tf32, fast, fast-graph, fast-bf16,
fast-bf16-graph, fast-compiled, fast-bf16-compiled-graph (the fast network through torch.compile: inductor,
max-autotune on CUDA; minutes of compiling per size), fused, fused-graph, fused-bf16, fused-bf16-graph (CUDA:
model/fused_network.py, Triton kernels tuned on the first call, each convolution in the form its rule picks; the
input features in one kernel, model/fused_features.py), fused-torch-features-bf16-graph (the same with
model/features.py's PyTorch features: the baseline of that kernel), fused-gather-bf16-graph (every convolution a
gather-GEMM, the form before products-first), fused-fold-bf16-graph (norms applied on load by the gathering
convolutions that read them: fewer launches for narrow networks), fused-pdl-bf16-graph and
fused-fold-pdl-bf16-graph (each Triton kernel a programmatic dependent launch: Hopper's overlap of a launch with
the kernel before it), fused-persistent-bf16-graph (the plan as one persistent kernel, a grid barrier
between its phases: model/persistent_network.py), fused-fold-persistent-bf16-graph (the same on the folded
plan), exported (the torch.export program of deploy/export.py, loaded
back: net is not separate there), exported-graph, exported-fused (CUDA: the export's program of the fused bf16
path, its Triton launchers operators in it, loaded back), exported-fused-graph (that program replayed as one CUDA
graph: what deploy/runner.py --fused runs). Graph modes copy each call's inputs into the graph's static buffers
inside the timed call, as a tool would. The error column is the
largest |whole - eager whole| over the largest eager displacement. --features picks the inputs: `paper`
(positions, as the paper) or `body` (velocity, body, Laplacian, gravity in local frames: the pants scene's;
16 random capsules). Median over repeats after warm-up. Usage:
  python bench/infer.py [--device cpu|cuda] [--cases flag-cpu,15k] [--sizes RC13,RC9,RC9x/2,RC9x/4]
      [--modes eager,fast,fast-bf16,exported] [--features paper|body] [--batch 1] [--repeats 20] [--warmup 5]
      [--threads N] [--out table.md] [--profile]
"""
from __future__ import annotations

import argparse
import io
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch.export.passes import move_to_device_pass

from deploy.export import PROGRAM, export_upsampler, sample_inputs
from deploy.runner import FUSED_PROGRAM
from geometry.loop_subdivision import loop_subdivide
from meshops import build_operators
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameBatch
from model.cuda_graph import CapturedCall
from model.inference import FastRegressor, FastUpsampler, needed_inputs
from model.mesh_hierarchy import mesh_hierarchy
from model.networks import NetworkSpec, build_network
from scenes.flag_mesh import flag_cloth

ARCH = "D62 D124 D248 D D248 D_3 D248"
# Low-res grid edge lengths, as bench/cloth_solver.py: the CPU-profile flag, the paper-sized flag, a ~15k-vertex high-res.
CASES = {"flag-cpu": 0.12, "flag": 0.08, "15k": 0.046}
SIZES = {"RC13": ("RC13", 1.0), "RC9": ("RC9", 1.0), "RC9x/2": ("RC9", 0.5), "RC9x/4": ("RC9", 0.25)}
FEATURES = {"paper": FeatureSpec(),
            "body": FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")}
# mode -> (path, matmul dtype, CUDA graph, TF32, network through torch.compile)
MODES = {"eager": ("eager", torch.float32, False, False, False),
         "graph": ("eager", torch.float32, True, False, False),
         "eager-tf32": ("eager", torch.float32, False, True, False),
         "graph-tf32": ("eager", torch.float32, True, True, False),
         "fast": ("fast", torch.float32, False, False, False),
         "fast-graph": ("fast", torch.float32, True, False, False),
         "fast-bf16": ("fast", torch.bfloat16, False, False, False),
         "fast-bf16-graph": ("fast", torch.bfloat16, True, False, False),
         "fast-compiled": ("fast", torch.float32, False, False, True),
         "fast-bf16-compiled-graph": ("fast", torch.bfloat16, True, False, True),
         "fused": ("fused", torch.float32, False, False, False),
         "fused-graph": ("fused", torch.float32, True, False, False),
         "fused-bf16": ("fused", torch.bfloat16, False, False, False),
         "fused-bf16-graph": ("fused", torch.bfloat16, True, False, False),
         "fused-torch-features-bf16-graph": ("fused-torch-features", torch.bfloat16, True, False, False),
         "fused-gather-bf16-graph": ("fused-gather", torch.bfloat16, True, False, False),
         "fused-fold-bf16-graph": ("fused-fold", torch.bfloat16, True, False, False),
         "fused-pdl-bf16-graph": ("fused-pdl", torch.bfloat16, True, False, False),
         "fused-fold-pdl-bf16-graph": ("fused-fold-pdl", torch.bfloat16, True, False, False),
         "fused-persistent-bf16-graph": ("fused-persistent", torch.bfloat16, True, False, False),
         "fused-fold-persistent-bf16-graph": ("fused-fold-persistent", torch.bfloat16, True, False, False),
         "exported": ("exported", torch.float32, False, False, False),
         "exported-graph": ("exported", torch.float32, True, False, False),
         "exported-fused": ("exported-fused", torch.bfloat16, False, False, False),
         "exported-fused-graph": ("exported-fused", torch.bfloat16, True, False, False)}
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
    return low, subdivision, faces, meshes, seconds


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


def kernel_table(fn, device: torch.device) -> str:
    """torch.profiler's table of 5 calls of `fn`, the most expensive kernels (or CPU ops) first."""
    activities = [torch.profiler.ProfilerActivity.CPU]
    if device.type == "cuda":
        activities.append(torch.profiler.ProfilerActivity.CUDA)
    with torch.inference_mode(), torch.profiler.profile(activities=activities) as profile:
        for _ in range(5):
            fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
    key = "self_device_time_total" if device.type == "cuda" else "self_cpu_time_total"
    table = profile.key_averages().table(sort_by=key, row_limit=20)
    if device.type != "cuda":
        return table
    # The last call's kernels in launch order: which convolution (or norm) costs what.
    kernels = sorted((e for e in profile.events() if e.device_type == torch.autograd.DeviceType.CUDA),
                     key=lambda e: e.time_range.start)
    last = kernels[len(kernels) - len(kernels) // 5:]
    launches = "\n".join(f"  {i:3d} {e.device_time:8.1f} us  {e.name[:90]}" for i, e in enumerate(last))
    return f"{table}\nkernels of the last call in launch order ({sum(e.device_time for e in last):.1f} us):\n{launches}"


def regressor(spec: FeatureSpec, size: str, faces: np.ndarray, rest: np.ndarray) -> FeatureRegressor:
    """The size's network with random weights behind plausible normalisations (inputs centred on the rest mesh's
    scale, displacements of ~1 cm)."""
    conv, width = SIZES[size]
    net = build_network(NetworkSpec(ARCH, conv, "max", width, in_channels=spec.channels))
    offset, scale = 0.1 * torch.randn(spec.channels), 0.5 + torch.rand(spec.channels)
    return FeatureRegressor(net, spec, faces, rest, offset, scale, 0.01).eval()


def paths(model: FeatureRegressor, mesh, subdivision, faces, mode: str, inputs: dict, device: torch.device):
    """(net, subd, whole) of a mode: functions of the tensors `inputs` (the program inputs of deploy/export.py);
    net is None where it is not separate."""
    kind, dtype, _, _, compiled = MODES[mode]
    names = list(inputs)
    if kind == "exported-fused":
        files = export_upsampler(model, mesh, subdivision, faces, frame_time=1 / 60, fused_device=str(device))
        # Its operators are registered here by the project's own modules (the export's package is their copy).
        compiled = torch.export.load(io.BytesIO(files[FUSED_PROGRAM])).module()
        fast = FastUpsampler(FastRegressor(model, mesh.to("cpu")), subdivision).to(device)
        return None, lambda *x: fast.subdivide(x[0]), lambda *x: compiled(**dict(zip(names, x)))
    if kind == "exported":
        files = export_upsampler(model, mesh, subdivision, faces, frame_time=1 / 60)
        program = torch.export.load(io.BytesIO(files[PROGRAM]))
        if device.type != "cpu":
            program = move_to_device_pass(program, device)
        module = program.module()
        fast = FastUpsampler(FastRegressor(model, mesh.to("cpu")), subdivision).to(device)
        return None, lambda *x: fast.subdivide(x[0]), lambda *x: module(**dict(zip(names, x)))
    model, mesh = model.to(device), mesh.to(device)
    if kind in ("fast", "fused", "fused-gather", "fused-fold", "fused-pdl", "fused-fold-pdl",
                "fused-persistent", "fused-fold-persistent", "fused-torch-features"):
        products = False if kind == "fused-gather" else None
        upsampler = FastUpsampler(FastRegressor(model, mesh, dtype, fused=kind != "fast", products=products,
                                                fold_norms="fold" in kind, pdl="pdl" in kind,
                                                persistent="persistent" in kind,
                                                fused_features=kind != "fused-torch-features"),
                                  subdivision).to(device)
        if compiled:     # inductor may fuse the elementwise passes (pad, norm, pooling) into fewer kernels
            upsampler.regressor.network = torch.compile(
                upsampler.regressor.network, dynamic=False,
                mode="max-autotune-no-cudagraphs" if device.type == "cuda" else "default")
        features = upsampler.regressor.features(_frame(upsampler.subdivide, names, list(inputs.values())))
        return ((lambda *x: upsampler.regressor.network(features)), lambda *x: upsampler.subdivide(x[0]),
                lambda *x: upsampler(**dict(zip(names, x))))
    stencil = FastUpsampler(FastRegressor(model, mesh), subdivision).to(device)
    order = stencil.regressor.new_of                  # eager runs in the mesh's own vertex order
    smooth = lambda low: stencil.subdivide(low).index_select(1, order)  # noqa: E731
    encoded, _ = model.encode(_frame(smooth, names, list(inputs.values())))

    def whole(*x):
        frame = _frame(smooth, names, x)
        return frame.positions + model(frame, mesh)
    return (lambda *x: model.net(encoded, mesh)), lambda *x: smooth(x[0]), whole


def _frame(subdivide, names: list[str], values) -> FrameBatch:
    given = dict(zip(names, values))
    smooth = lambda name: None if name not in given else subdivide(given[name])  # noqa: E731
    return FrameBatch(smooth("low_positions"), smooth("low_previous"), smooth("low_before_previous"),
                      given.get("capsule_a"), given.get("capsule_b"), given.get("radius_a"), given.get("radius_b"),
                      given.get("gravity"), given.get("frame_time"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--cases", default="flag-cpu,15k", help=f"comma-separated of {', '.join(CASES)}")
    parser.add_argument("--sizes", default=",".join(SIZES), help=f"comma-separated of {', '.join(SIZES)}")
    parser.add_argument("--modes", default="eager,fast,fast-bf16,exported",
                        help=f"comma-separated of {', '.join(MODES)}")
    parser.add_argument("--features", default="paper", choices=sorted(FEATURES))
    parser.add_argument("--batch", type=int, default=1, help="frames per call")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--out", help="also write the table (markdown) here")
    parser.add_argument("--profile", action="store_true",
                        help="after each row, the kernels of 5 whole calls by device time (torch.profiler)")
    args = parser.parse_args()
    device = torch.device(args.device)
    modes = args.modes.split(",")
    if device.type == "cuda" and not torch.cuda.is_available():
        sys.exit(f"error: device '{args.device}' requested but torch finds no CUDA device")
    unknown = [m for m in modes if m not in MODES]
    if unknown or (device.type != "cuda" and any(MODES[m][2] or MODES[m][3] or "fused" in MODES[m][0]
                                                 for m in modes)):
        sys.exit(f"error: --modes {args.modes}: modes are {', '.join(MODES)}; graph, tf32 and fused ones need "
                 f"CUDA")
    torch.set_flush_denormal(True)
    torch.backends.cuda.matmul.allow_bf16_reduced_precision_reduction = False     # bf16 GEMMs sum in fp32
    if args.threads:
        torch.set_num_threads(args.threads)
    sizes = args.sizes.split(",")
    convs = sorted({SIZES[s][0] for s in sizes})
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    header = ("| mesh | high-res V | size | params | mode | net ms | SubD ms | whole ms | net x eager | "
              "whole x eager | error vs eager | paper DL+SubD ms (hv) |\n|" + "---|" * 12)
    title = (f"device: {where}; {args.features} features, {args.batch} frame(s) per call; median of {args.repeats} "
             f"after {args.warmup} warm-up; torch {torch.__version__}")
    print(f"{title}\n{header}", flush=True)
    rows = []
    for case in args.cases.split(","):
        low, subdivision, faces, meshes, build_seconds = build_case(CASES[case], convs, levels=9)
        n_high = subdivision.shape[0]
        print(f"<!-- {case}: operators for {n_high} vertices built in {build_seconds:.1f} s -->", flush=True)
        paper_hv = min(PAPER_MS, key=lambda hv: abs(hv - n_high))
        rest = subdivision @ low
        for size in sizes:
            torch.manual_seed(0)
            model = regressor(FEATURES[args.features], size, faces, rest)
            names = needed_inputs(model)
            cpu_inputs = sample_inputs(names, low, batch=args.batch, capsules=16)
            inputs = tuple(x.to(device) for x in cpu_inputs.values())
            _, subdivide, eager = paths(model, meshes[SIZES[size][0]], subdivision, faces, "eager",
                                        dict(zip(names, inputs)), device)
            with torch.inference_mode():
                reference = eager(*inputs)
                largest = (reference - subdivide(*inputs)).abs().max()
            baseline = {}
            for mode in modes:
                torch.backends.cuda.matmul.fp32_precision = "tf32" if MODES[mode][3] else "ieee"
                fns = paths(model, meshes[SIZES[size][0]], subdivision, faces, mode,
                            dict(zip(names, inputs)), device)
                with torch.inference_mode():
                    calls = [None if fn is None else
                             (CapturedCall(fn, *inputs, warmup=args.warmup) if MODES[mode][2] else fn)
                             for fn in fns]
                    ms = [None if call is None else timed(lambda: call(*inputs), args.repeats, args.warmup, device)
                          for call in calls]
                    error = float((calls[2](*inputs) - reference).abs().max() / largest)
                if mode == "eager":
                    baseline = {"net": ms[0], "whole": ms[2]}
                ratio = lambda key, value: "-" if value is None or key not in baseline else \
                    f"{baseline[key] / value:.2f}"  # noqa: E731
                cell = lambda value: "-" if value is None else f"{value:.2f}"  # noqa: E731
                row = (f"| {case} | {n_high} | {size} | {model.net.parameter_count():,} | {mode} | "
                       f"{cell(ms[0])} | {cell(ms[1])} | {cell(ms[2])} | {ratio('net', ms[0])} | "
                       f"{ratio('whole', ms[2])} | {error:.1e} | {PAPER_MS[paper_hv][size]} ({paper_hv}) |")
                rows.append(row)
                print(row, flush=True)
                if args.profile:
                    print(kernel_table(lambda: calls[2](*inputs), device), flush=True)
    if args.out:
        Path(args.out).write_text(f"{title}\n\n{header}\n" + "\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
