"""model.triton_stencil's kernel against scipy's sparse product: Loop subdivision of a batch, and with rows and an
addend (the sum and reorder after the fused network), for channel counts that are not a power of two, a stencil
one entry wide and an empty batch. On CUDA, and on the CPU through Triton's interpreter where Triton is installed
(not a CPU requirement: this file then runs itself in a subprocess with TRITON_INTERPRET=1, set before Triton is
imported). Where the kernel runs, the whole upsampler with the fused network (which runs its subdivision and its
last sum in this kernel) is checked against the one with ATen's network too."""
from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import torch

from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor
from model.feature_spec import FeatureSpec
from model.inference import FastRegressor, FastUpsampler, padded_stencil
from model.networks import NetworkSpec, build_network
from model_meshes import build_hierarchy, grid_mesh
from triton_interpreted import interpreted_errors

TOLERANCE = 1e-6       # of the largest |expected| value: fp32 sums of a few products against scipy's fp64
UPSAMPLER_TOLERANCE = 1e-5      # the fused fp32 network against ATen's: summation order (tests/model/test_inference)


def _relative(got: np.ndarray, expected: np.ndarray) -> float:
    return float(np.abs(got - expected).max() / max(np.abs(expected).max(), 1e-30))


def _stencil_errors(device: str) -> dict[str, float]:
    """Per case, the kernel's largest error relative to the largest |value| of scipy's product."""
    from model.triton_stencil import stencil

    low, low_faces = grid_mesh(5, 6)
    subdivision, _ = loop_subdivide(low, low_faces, 2)
    n_rows = subdivision.shape[0]
    columns, weights = (torch.as_tensor(a, device=device) for a in padded_stencil(subdivision))
    generator = np.random.default_rng(4)
    errors = {}
    for channels in (3, 1, 5):
        frames = generator.normal(size=(3, len(low), channels)).astype(np.float32)
        x = torch.as_tensor(frames, device=device)
        expected = np.stack([subdivision @ frame.astype(np.float64) for frame in frames])
        errors[f"product C={channels}"] = _relative(stencil(columns, weights, x, None, None).cpu().numpy(), expected)
        rows = generator.permutation(n_rows)[:n_rows - 7]           # a reorder that also leaves rows out
        add = generator.normal(size=(3, n_rows, channels)).astype(np.float32)
        got = stencil(columns, weights, x, torch.as_tensor(rows, device=device), torch.as_tensor(add, device=device))
        assert got.shape == (3, n_rows - 7, channels)
        errors[f"rows and add C={channels}"] = _relative(got.cpu().numpy(), (expected + add)[:, rows])
    x = torch.as_tensor(generator.normal(size=(2, len(low), 3)).astype(np.float32), device=device)
    one_wide = stencil(torch.arange(len(low), device=device)[:, None], torch.ones(len(low), 1, device=device), x,
                       None, None)
    errors["one entry a row"] = float((one_wide - x).abs().max())      # exactly x: 1 * value
    assert stencil(columns, weights, x[:0], None, None).shape == (0, n_rows, 3)
    errors["upsampler"] = _upsampler_error(device)
    return errors


def _upsampler_error(device: str) -> float:
    """FastUpsampler with the fused network (fp32) against the one with ATen's network, whole frames."""
    low, low_faces = grid_mesh(4, 5)
    subdivision, faces = loop_subdivide(low, low_faces, 1)
    high = (subdivision @ low).astype(np.float32)
    mesh = build_hierarchy(faces, len(high), 7, 4)
    spec = FeatureSpec(("position", "laplacian"))
    net = build_network(NetworkSpec("D8 D16 D D16", "RC7", "max", in_channels=spec.channels))
    model = FeatureRegressor(net, spec, faces, high, torch.randn(spec.channels), torch.rand(spec.channels) + 0.5,
                             0.3).eval()
    reference = FastUpsampler(FastRegressor(model, mesh), subdivision).to(device)
    fused = FastUpsampler(FastRegressor(model, mesh, fused=True), subdivision).to(device)
    assert fused.kernel and not reference.kernel
    positions = torch.as_tensor(low, dtype=torch.float32) + 0.05 * torch.randn(2, *low.shape)
    with torch.no_grad():
        expected = reference(positions.to(device))
        got = fused(positions.to(device))
    return _relative(got.cpu().numpy(), expected.cpu().numpy())


def _check(errors: dict[str, float]) -> None:
    print(errors)
    assert len(errors) == 8 and errors["one entry a row"] == 0.0
    assert errors.pop("upsampler") < UPSAMPLER_TOLERANCE and max(errors.values()) < TOLERANCE


@pytest.mark.skipif(importlib.util.find_spec("triton") is None or torch.cuda.is_available(),
                    reason="needs Triton; where CUDA is, the test below runs the compiled kernel instead")
def test_kernel_interpreted_on_the_cpu_is_the_sparse_product():
    _check(interpreted_errors(__file__))


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="needs CUDA and Triton")
def test_kernel_on_cuda_is_the_sparse_product():
    _check(_stencil_errors("cuda"))


@pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="needs Triton")
@pytest.mark.parametrize("rows", [False, True])
def test_kernel_compiles_for_a_hopper_gpu_without_one(rows):
    """Triton's compiler for sm_90 on any machine: what the interpreter lets through fails here first."""
    from triton import compile as compile_kernel
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    from model.triton_stencil import BLOCK, _stencil_kernel

    constants = {"W": 7, "C": 3, "C_PAD": 4, "ROWS": rows, "ADD": rows, "BLOCK_ROWS": BLOCK}
    integers = {"columns_ptr": "*i64", "rows_ptr": "*i64", "n_out": "i32", "n_in": "i32", "n_stencil": "i32"}
    signature = {name: "constexpr" if name in constants else integers.get(name, "*fp32")
                 for name in _stencil_kernel.arg_names}
    kernel = compile_kernel(ASTSource(_stencil_kernel, signature, constexprs=constants),
                            target=GPUTarget("cuda", 90, 32), options={"num_warps": 4})
    assert ".entry _stencil_kernel" in kernel.asm["ptx"]


if __name__ == "__main__":      # the interpreted run of test_kernel_interpreted_on_the_cpu_is_the_sparse_product
    print(json.dumps(_stencil_errors("cpu")))
