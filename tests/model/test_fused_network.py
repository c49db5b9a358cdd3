"""The fused network (one kernel per convolution) against the eager encoder-decoder.

The plan and its PyTorch executor are checked on every machine: same output as the eager network, one launch per
convolution, pooling chains composed into 2^k-wide maps. The Triton kernel is checked against that executor
wherever Triton runs: on CUDA (fp32 and bf16), and on the CPU through Triton's interpreter when Triton is installed
(it is not a CPU requirement: this file then runs itself in a subprocess with TRITON_INTERPRET=1, which must be
set before Triton is imported). The interpreter cannot run bf16 matmuls, so bf16 is checked on CUDA only."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from model.fused_network import PROLOGUE_AFFINE, PROLOGUE_NORM, FusedNetwork, fused_plan, run_plan_reference
from model.networks import NetworkSpec, build_network
from model_meshes import build_hierarchy, grid_mesh

FP32_TOLERANCE = 1e-5      # of the largest |output|: sums-based variance and summation order, nothing else
BF16_TOLERANCE = 5e-2      # the bf16 fast path's bound (tests/model/test_inference.py)
# Two pooling chains and three unpoolings in a row in the second: the maps the Table 3 networks need (D_3).
ARCHS = ["D8 D16 D D16", "D8 D16 D D16 D_2 D8"]
CASES = [(pool, arch) for pool in ("max", "avg") for arch in ARCHS]


def _case(pool: str, arch: str, batch: int = 2):
    torch.manual_seed(0)
    vertices, faces = grid_mesh(10, 12)
    mesh = build_hierarchy(faces, len(vertices), 7, 7)
    net = build_network(NetworkSpec(arch, "RC7", pool, in_channels=5)).eval()
    for conv in net.convs:                  # larger than the default init, so every layer's values matter
        torch.nn.init.normal_(conv.weight, std=0.5)
    offset, scale = torch.randn(5), torch.rand(5) + 0.5
    x = torch.randn(batch, len(vertices), 5) * scale + offset
    x[1] *= 3.0                             # frames with different statistics: norms are per frame
    return net, mesh, offset, scale, x


def _relative(got: torch.Tensor, expected: torch.Tensor) -> float:
    return float((got.float().cpu() - expected).abs().max() / expected.abs().max())


def _reference(net, mesh, offset, scale, x) -> torch.Tensor:
    with torch.no_grad():
        return run_plan_reference(fused_plan(net, mesh, 0.3), list(mesh.conv), x, offset, scale,
                                  net.pool_kind == "max")


@pytest.mark.parametrize("pool,arch", CASES)
def test_plan_gives_the_eager_output(pool, arch):
    net, mesh, offset, scale, x = _case(pool, arch)
    with torch.no_grad():
        eager = net((x - offset) / scale, mesh) * 0.3
    assert _relative(_reference(net, mesh, offset, scale, x), eager) < FP32_TOLERANCE


def test_plan_has_one_launch_per_convolution_and_composed_maps():
    net, mesh, *_ = _case("max", ARCHS[1])
    plan = fused_plan(net, mesh, 0.3)
    assert len(plan) == len(net.convs)
    assert sum(conv.stats for conv in plan) == sum(step.op == "norm" for step in net.steps)
    assert plan[0].segments[0].prologue == PROLOGUE_AFFINE and plan[0].segments[0].rows is None
    widths = {conv.segments[0].rows.shape[1] for conv in plan if conv.segments[0].rows is not None}
    # unpooling chains stay 1 wide; D8 -> D16 one pooling, D16 D -> D16 two, D16 D_2 -> D8 three
    assert widths == {1, 2, 4, 8}
    deepest = plan[len([b for b in net.arch.blocks if b is not None]) - 1]
    assert deepest.segments[0].rows.shape == (mesh.vertex_counts[-1], 8)
    for conv in plan:
        assert conv.weight.shape[0] == net.convs[0].size * sum(s.channels for s in conv.segments)
        if len(conv.segments) == 2:     # up block: unpooled raw coarse output, then the normalised skip
            assert conv.segments[0].prologue != PROLOGUE_NORM and conv.segments[1].prologue == PROLOGUE_NORM
    assert not plan[-1].stats and not plan[-2].stats


def test_fused_network_refuses_what_it_cannot_run():
    net, mesh, offset, scale, x = _case("avg", ARCHS[0])
    decoder = build_network(NetworkSpec("U8 U U3", "RC7", in_channels=5, coarse_vertices=mesh.vertex_counts[3]))
    with pytest.raises(ValueError, match="encoder-decoder only"):
        fused_plan(decoder, mesh, 1.0)
    if os.environ.get("TRITON_INTERPRET") != "1":
        with pytest.raises(ValueError, match="runs on CUDA"):
            FusedNetwork(net, mesh, offset, scale, 0.3)(x)


def _kernel_errors(device: str, dtype: torch.dtype) -> dict[str, float]:
    errors = {}
    for pool, arch in CASES:
        net, mesh, offset, scale, x = _case(pool, arch)
        expected = _reference(net, mesh, offset, scale, x)
        fused = FusedNetwork(net, mesh, offset, scale, 0.3, dtype).to(device)
        with torch.no_grad():
            errors[f"{pool} {arch}"] = _relative(fused(x.to(device)), expected)
            single = fused(x[1:].to(device))            # a frame alone: the batch does not mix frames
            errors[f"{pool} {arch} alone"] = _relative(single, expected[1:])
    return errors


@pytest.mark.skipif(importlib.util.find_spec("triton") is None, reason="Triton is not installed")
def test_triton_kernel_interpreted_on_the_cpu_matches_the_plan():
    here = Path(__file__).parent
    env = dict(os.environ, TRITON_INTERPRET="1",
               PYTHONPATH=os.pathsep.join([str(here), str(here.parents[1]), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    errors = json.loads(done.stdout.splitlines()[-1])
    print(errors)
    assert len(errors) == 2 * len(CASES) and max(errors.values()) < FP32_TOLERANCE


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="needs CUDA and Triton")
@pytest.mark.parametrize("dtype,tolerance", [(torch.float32, FP32_TOLERANCE), (torch.bfloat16, BF16_TOLERANCE)],
                         ids=["fp32", "bf16"])
def test_triton_kernel_on_cuda_matches_the_plan(dtype, tolerance):
    errors = _kernel_errors("cuda", dtype)
    print(errors)
    assert max(errors.values()) < tolerance


if __name__ == "__main__":      # the interpreted run of test_triton_kernel_interpreted_on_the_cpu_matches_the_plan
    print(json.dumps(_kernel_errors("cpu", torch.float32)))
