"""A trained upsampler as a self-contained exported program: what a tool needs to upsample frames without the
project's code.

`export_upsampler` traces model.inference.FastUpsampler (Loop subdivision as a padded-stencil gather, the input
features, the reordered network with its normalisations folded in, the un-permutation) with `torch.export`, batch
size and capsule count left dynamic, and returns the files of an export folder (docs/artifacts.md, "Exported
upsampler"): the program (`torch.export.save`, written without example inputs so that loading it unpickles
nothing: deploy/runner.py refuses any program that would), a JSON manifest naming the program's inputs, the low-
and high-res faces, and a copy of deploy/runner.py. Before returning, the loaded-back program is run against the
eager fp32 network on a sample batch; a difference beyond EXPORT_TOLERANCE is an error, not a file.

Exported on CUDA (`fused_device`), the folder also holds what a user deploys there: the same learned path with the
fused bf16 network (model.fused_network and model.fused_features, their Triton launchers registered as
torch.library.triton_op operators, learned_cloth::*), exported as a second program (`FUSED_PROGRAM`, saved and
checked like the first, within FUSED_TOLERANCE) in which each launcher is one operator, and the operators' source
as a package of the folder (`KERNELS`: the project modules that define them, copied with their imports of each
other made relative), which deploy/runner.py imports before loading that program: torch with Triton (which
PyTorch's CUDA wheels bring) and no project code. AOTInductor, which would compile the kernels into the package
instead, was the first form; its loader crashed for any package (a plain ATen one too) in the torch 2.11 image the
GPU tests run in, so it could not be verified there.
"""
from __future__ import annotations

import ast
import copy
import io
import json
import re
import sys
from pathlib import Path
from typing import Callable
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp
import torch

from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor
from model.features import FrameBatch
from model.inference import FUSED_FORMS, FastRegressor, FastUpsampler, needed_inputs
from model.mesh_hierarchy import MeshHierarchy
from deploy.runner import (FORMAT, FUSED_PROGRAM, HIGH_FACES, KERNELS, LOW_FACES, OPERATOR_NAMESPACE, OPERATORS,
                           PROGRAM)

MANIFEST, RUNNER = "upsampler.json", "runner.py"
# The project modules that define the fused operators, in the export's KERNELS package (model/<name>.py).
KERNEL_MODULES = ("triton_conv", "triton_features", "triton_stencil", "persistent_kernel", "persistent_spec",
                  "layers", "local_frames", "cuda_graph")
# What an export folder holds (FUSED_PROGRAM and KERNELS only when exported on CUDA).
EXPORT_FILES = (PROGRAM, MANIFEST, LOW_FACES, HIGH_FACES, RUNNER, FUSED_PROGRAM,
                *(f"{KERNELS}/{name}.py" for name in ("__init__", *KERNEL_MODULES)))
# Largest |exported - eager| displacement over the largest |eager| displacement of the export check (fp32; the
# two differ by summation order only: ~1e-6 in the tests, but 1.9e-4 for an untrained RC13 with body inputs at 15k
# vertices in bench/infer.py, where instance norms of near-constant random features amplify rounding).
EXPORT_TOLERANCE = 1e-3
# The fused program's bound against the eager fp32 network, the same measure: its hidden layers are bf16 (0.3-1 %
# of the largest displacement measured, model/inference.py), held to issue 36's 1 %.
FUSED_TOLERANCE = 1e-2
# name -> (shape, meaning) of every input a program may take (model.inference.UPSAMPLER_INPUTS, deploy.runner.INPUTS);
# its manifest lists those it does take, in order.
INPUTS = {
    "low_positions": ("(B, V_low, 3)", "low-res positions of B frames, in the reference frame of the training "
                                       "data (world or torso, as the dataset was)"),
    "low_previous": ("(B, V_low, 3)", "low-res positions one frame earlier (the frame itself at a sequence's "
                                      "first frame: zero velocity)"),
    "low_before_previous": ("(B, V_low, 3)", "low-res positions two frames earlier, by the same rule"),
    "capsule_a": ("(B, P, 3)", "end point a of each body capsule, same frame"),
    "capsule_b": ("(B, P, 3)", "end point b of each body capsule, same frame"),
    "radius_a": ("(P,)", "each capsule's radius at end a"),
    "radius_b": ("(P,)", "each capsule's radius at end b"),
    "gravity": ("(B, 3)", "unit direction of gravity, same frame"),
    "frame_time": ("()", "seconds between consecutive frames (float32 scalar)"),
}


def coarse_faces(subdivision: sp.spmatrix, high_faces: np.ndarray, high_rest: np.ndarray) -> np.ndarray:
    """The low-res faces whose Loop subdivision (geometry.loop_subdivision: every face split into four in place,
    corners first) is `subdivision` with `high_faces`; ValueError if there are none."""
    n_low, faces, levels = subdivision.shape[1], np.asarray(high_faces, dtype=np.int64), 0
    while len(faces) and faces.max() >= n_low and len(faces) % 4 == 0:
        quads = faces.reshape(-1, 4, 3)
        faces, levels = np.stack([quads[:, 0, 0], quads[:, 1, 1], quads[:, 2, 2]], axis=1), levels + 1
    try:
        again, again_faces = loop_subdivide(high_rest[:n_low], faces, levels)
    except ValueError as err:
        raise ValueError(f"the high-res mesh is not a Loop subdivision of a low-res mesh ({err})") from None
    if not np.array_equal(again_faces, high_faces) or abs(again - sp.csr_matrix(subdivision)).max() > 1e-12:
        raise ValueError("the subdivision matrix is not the Loop subdivision of the low-res mesh under its faces")
    return faces


def sample_inputs(names: tuple[str, ...], low_rest: np.ndarray, batch: int = 2, capsules: int = 2,
                  frame_time: float = 1 / 60, seed: int = 0) -> dict[str, torch.Tensor]:
    """Plausible values of the program inputs `names`: the rest mesh moved a little, capsules near it."""
    generator = torch.Generator().manual_seed(seed)
    normal = lambda *shape: torch.randn(*shape, generator=generator)  # noqa: E731
    low = torch.as_tensor(low_rest, dtype=torch.float32)
    extent = float((low.max(0).values - low.min(0).values).max())
    near = lambda *shape: low.mean(0) + 0.3 * extent * normal(*shape)  # noqa: E731
    values = {"low_positions": low + 0.02 * extent * normal(batch, *low.shape)}
    values["low_previous"] = values["low_positions"] + 0.005 * extent * normal(batch, *low.shape)
    values["low_before_previous"] = values["low_previous"] + 0.005 * extent * normal(batch, *low.shape)
    values.update(capsule_a=near(batch, capsules, 3), capsule_b=near(batch, capsules, 3),
                  radius_a=0.05 * extent * (1 + torch.rand(capsules, generator=generator)),
                  radius_b=0.05 * extent * (1 + torch.rand(capsules, generator=generator)),
                  gravity=torch.tensor([0.0, -1.0, 0.0]).expand(batch, 3).clone(),
                  frame_time=torch.tensor(frame_time, dtype=torch.float32))
    return {name: values[name] for name in names}


def eager_displacement(model: FeatureRegressor, mesh: MeshHierarchy, subdivision: sp.spmatrix,
                       inputs: Mapping[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """S x_low (B, V_high, 3) and the eager fp32 network's displacement (a model on the CPU) for program inputs:
    the reference an exported program is checked against."""
    def smooth(name: str) -> torch.Tensor | None:
        low = inputs.get(name)
        return None if low is None else torch.as_tensor(np.stack([subdivision @ x for x in low.double().numpy()]),
                                                         dtype=torch.float32)
    positions = smooth("low_positions")
    frame = FrameBatch(positions, smooth("low_previous"), smooth("low_before_previous"), inputs.get("capsule_a"),
                       inputs.get("capsule_b"), inputs.get("radius_a"), inputs.get("radius_b"),
                       inputs.get("gravity"), inputs.get("frame_time"))
    with torch.no_grad():
        return positions, model(frame, mesh.to("cpu"))


def export_upsampler(model: FeatureRegressor, mesh: MeshHierarchy, subdivision: sp.spmatrix,
                     high_faces: np.ndarray, frame_time: float | None = None,
                     provenance: Mapping[str, Any] | None = None,
                     fused_device: str | None = None) -> dict[str, bytes]:
    """The files of an export folder (name -> contents) of a trained model on its hierarchy and subdivision.

    `frame_time` (seconds between the training frames) is the manifest's default for the program's `frame_time`
    input; a model with velocity or acceleration inputs needs it. `provenance` (plain values) goes into the
    manifest. `fused_device` (a CUDA device): also the program of the fused bf16 path on that device and the
    package of its operators. ValueError for a network or mesh that cannot be exported, or an export that does not
    reproduce the eager network."""
    if not isinstance(model, FeatureRegressor):
        raise ValueError(f"only an encoder-decoder on per-vertex features can be exported, not a "
                         f"{type(model).__name__}")
    names = needed_inputs(model)
    if "frame_time" in names and frame_time is None:
        raise ValueError(f"the model's inputs ({', '.join(model.spec.inputs)}) need the frame time of its "
                         f"training data")
    model = copy.deepcopy(model).cpu().eval()          # traced on the CPU; the caller's model stays where it is
    high_rest = model.features.rest.numpy().astype(np.float64)
    low_faces = coarse_faces(subdivision, high_faces, high_rest)
    upsampler = FastUpsampler(FastRegressor(model, mesh), subdivision).eval()
    example = sample_inputs(names, high_rest[:subdivision.shape[1]], frame_time=frame_time or 1 / 60)
    program, loaded = _saved(_exported(upsampler, example))
    check = lambda run: _difference_from_eager(run, model, mesh, subdivision, names, high_rest,  # noqa: E731
                                               frame_time)
    difference = _within(check(loaded), EXPORT_TOLERANCE, "the exported program")
    files = {PROGRAM: program}
    fused = None
    if fused_device is not None:
        files[FUSED_PROGRAM], fused = _fused_program(model, mesh, subdivision, example, fused_device, check)
        files.update(kernel_package())
    manifest = {
        "format": FORMAT, "program": PROGRAM, "torch": torch.__version__,
        "inputs": [{"name": name, "shape": INPUTS[name][0], "meaning": INPUTS[name][1]} for name in names],
        "output": {"shape": "(B, V_high, 3)", "meaning": "high-res positions, same frame as the inputs"},
        "n_low_vertices": int(subdivision.shape[1]), "n_high_vertices": int(subdivision.shape[0]),
        "low_faces": LOW_FACES, "high_faces": HIGH_FACES,
        "frame_time": frame_time if "frame_time" in names else None,
        "features": {"inputs": list(model.spec.inputs), "input_frame": model.spec.input_frame,
                     "output_frame": model.spec.output_frame, "frame_tangent": model.spec.frame_tangent},
        "export_check": {"max_difference_vs_eager": difference, "tolerance": EXPORT_TOLERANCE,
                         "meaning": "largest |exported - eager fp32| displacement over the largest |eager| one, "
                                    "on a sample batch at export"},
        "fused": fused,
        "provenance": dict(provenance or {}),
    }
    return {**files, MANIFEST: (json.dumps(manifest, indent=1) + "\n").encode(),
            LOW_FACES: _npy(low_faces.astype(np.int32)), HIGH_FACES: _npy(np.asarray(high_faces, dtype=np.int32)),
            RUNNER: (Path(__file__).parent / RUNNER).read_bytes()}


def _exported(upsampler: FastUpsampler, example: Mapping[str, torch.Tensor]) -> torch.export.ExportedProgram:
    """`upsampler` traced by torch.export with the batch size and the capsule count left dynamic."""
    batch, capsules = torch.export.Dim("batch", min=1), torch.export.Dim("capsules", min=1)
    dims = {"capsule_a": {0: batch, 1: capsules}, "capsule_b": {0: batch, 1: capsules},
            "radius_a": {0: capsules}, "radius_b": {0: capsules}, "frame_time": None}
    with torch.no_grad():
        return torch.export.export(upsampler, (), dict(example),
                                   dynamic_shapes={name: dims.get(name, {0: batch}) for name in example})


def _saved(program: torch.export.ExportedProgram) -> tuple[bytes, torch.nn.Module]:
    """The program's archive, written without example inputs (loading would unpickle them), and the module loaded
    back from those bytes: what a user gets."""
    program.example_inputs = None
    buffer = io.BytesIO()
    torch.export.save(program, buffer)
    return buffer.getvalue(), torch.export.load(io.BytesIO(buffer.getvalue())).module()


def _fused_program(model: FeatureRegressor, mesh: MeshHierarchy, subdivision: sp.spmatrix,
                   example: Mapping[str, torch.Tensor], device: str,
                   check: Callable[[Callable], float]) -> tuple[bytes, dict[str, Any]]:
    """The program of the learned path with the fused bf16 network on `device` (CUDA), each Triton launcher one
    learned_cloth operator in it, and its manifest entry; ValueError if it differs from the eager fp32 network by
    more than FUSED_TOLERANCE or calls an operator the KERNELS package does not define."""
    on_device = {name: value.to(device) for name, value in example.items()}
    fused, timings = _fastest_fused(model, mesh, subdivision, on_device)
    exported = _exported(fused, on_device)
    calls = sorted({str(node.target) for node in exported.graph.nodes
                    if str(node.target).startswith(f"{OPERATOR_NAMESPACE}.")})
    program, loaded = _saved(exported)
    if not {call.split(".")[1] for call in calls} <= set(OPERATORS):
        raise ValueError(f"the fused program calls {calls}, not all among the operators the runner knows "
                         f"({', '.join(OPERATORS)})")

    def run(**inputs: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return loaded(**{name: value.to(device) for name, value in inputs.items()}).cpu()
    difference = _within(check(run), FUSED_TOLERANCE, "the fused program")
    import triton       # the kernels' compiler, with PyTorch's CUDA builds (not a CPU requirement)
    return program, {"program": FUSED_PROGRAM, "kernels": KERNELS, "operators": calls, "device": "cuda",
                     "gpu": torch.cuda.get_device_name(device), "triton": triton.__version__,
                     "network": "model.fused_network: bf16 hidden layers, fp32 first and last convolutions",
                     "network_kernels": "persistent" if fused.regressor.network.persistent else "separate",
                     "ms_per_call": timings,
                     "max_difference_vs_eager": difference, "tolerance": FUSED_TOLERANCE,
                     "meaning": "a torch.export program of the learned path with the fused network, its Triton "
                                "launchers as the KERNELS package's operators (compiled by Triton at first call "
                                "for the GPU it runs on); the difference as export_check's"}


# An export times the fused network's two forms (model.inference.FUSED_FORMS: a launch a step, or the whole plan as
# one persistent kernel) on its GPU, this many replays each, and keeps the faster (0.14 against 0.20 ms for RC9 x/4
# at 15k vertices on an H200; 4x slower for RC13, whose wide layers lose cuBLAS's products: docs/performance.md).
FORM_TIMING_CALLS = 20


def _fastest_fused(model: FeatureRegressor, mesh: MeshHierarchy, subdivision: sp.spmatrix,
                   inputs: Mapping[str, torch.Tensor]) -> tuple[FastUpsampler, dict[str, float]]:
    """The fused upsampler in the faster of FUSED_FORMS on the inputs' device, and each form's median ms a call
    (the sample batch, one CUDA graph replayed FORM_TIMING_CALLS times after its capture's warm-up runs)."""
    from model.cuda_graph import CapturedCall
    names = list(inputs)
    forms, timings = {}, {}
    for name, options in FUSED_FORMS.items():
        upsampler = FastUpsampler(FastRegressor(model, mesh, torch.bfloat16, fused=True, **options),
                                  subdivision).to(next(iter(inputs.values())).device).eval()
        replay = CapturedCall(lambda *values, run=upsampler: run(**dict(zip(names, values))), *inputs.values())
        times = []
        for _ in range(FORM_TIMING_CALLS):
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            replay(*inputs.values())
            end.record()
            end.synchronize()
            times.append(start.elapsed_time(end))
        forms[name], timings[name] = upsampler, float(np.median(times))
    return forms[min(timings, key=timings.get)], timings


def kernel_package() -> dict[str, bytes]:
    """The KERNELS package's files (path in the export -> contents): model/<KERNEL_MODULES>.py with their imports
    of each other made relative, and an __init__.py importing those that register operators. ValueError if a
    module imports another project module (the package would not import without the project)."""
    files = {f"{KERNELS}/__init__.py": (
        '"""The fused network\'s Triton operators (learned_cloth::*) and the CUDA-graph replay the runner runs them in,\n'
        'copied from the project\'s model/ at export: importing this package registers the operators\n'
        '(deploy/runner.py does, before loading the fused program)."""\n'
        "from . import cuda_graph, persistent_kernel, triton_conv, triton_features, triton_stencil  # noqa: F401\n"
    ).encode()}
    for name in KERNEL_MODULES:
        source = re.sub(r"^(\s*)from model\.(\w+) import", r"\1from .\2 import",
                        (Path(__file__).parents[1] / "model" / f"{name}.py").read_text(), flags=re.M)
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.ImportFrom) and node.level:      # a module of the package itself
                outside = [f"model.{node.module}"] if node.module not in KERNEL_MODULES else []
            else:
                roots = ([alias.name for alias in node.names] if isinstance(node, ast.Import) else
                         [node.module] if isinstance(node, ast.ImportFrom) else [])
                outside = [root for root in roots if root.split(".")[0] not in (*sys.stdlib_module_names, "torch",
                                                                                 "triton", "numpy")]
            if outside:
                raise ValueError(f"model/{name}.py imports {outside[0]}: the operators' package would need the "
                                 f"project")
        files[f"{KERNELS}/{name}.py"] = source.encode()
    return files


def _difference_from_eager(run: Callable[..., torch.Tensor], model: FeatureRegressor, mesh: MeshHierarchy,
                           subdivision: sp.spmatrix, names: tuple[str, ...], high_rest: np.ndarray,
                           frame_time: float | None) -> float:
    """An exported path `run` (program inputs on the CPU as keywords -> high-res positions on the CPU) against
    the eager network on a sample batch of another size than the traced one: the largest difference of the
    displacements over the largest eager displacement."""
    inputs = sample_inputs(names, high_rest[:subdivision.shape[1]], batch=3, capsules=3,
                           frame_time=frame_time or 1 / 60, seed=1)
    smooth, expected = eager_displacement(model, mesh, subdivision, inputs)
    with torch.no_grad():
        got = run(**inputs) - smooth
    return float((got - expected).abs().max() / expected.abs().max().clamp_min(1e-30))


def _within(difference: float, tolerance: float, what: str) -> float:
    if not difference <= tolerance:
        raise ValueError(f"{what} differs from the eager network by {difference:.2e} of its largest displacement "
                         f"(tolerance {tolerance:g})")
    return difference


def _npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()
