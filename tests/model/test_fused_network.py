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

import numpy as np
import pytest
import torch

from model.fused_network import (NETWORK_INPUT, FusedConv, FusedNetwork, Prepare, aligned_plan, fused_plan,
                                 plan_phases, products_first, run_plan_reference, slot_weights)
from model.layers import mesh_conv
from model.inference import FastNetwork
from model.networks import NetworkSpec, build_network
from model_meshes import build_hierarchy, grid_mesh
from triton_interpreted import interpreted_errors

FP32_TOLERANCE = 1e-5      # of the largest |output|: sums-based variance and summation order, nothing else
# Two pooling chains and three unpoolings in a row in the second: the maps the Table 3 networks need (D_3);
# its 40-channel layers span several K chunks of the kernel, the narrower ones one.
ARCHS = ["D8 D16 D D16", "D8 D40 D D40 D_2 D8"]
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
    convs = [launch for launch in plan if isinstance(launch, FusedConv)]
    prepares = [launch for launch in plan if isinstance(launch, Prepare)]
    norms = sum(step.op == "norm" for step in net.steps)
    assert len(convs) == len(net.convs) and plan[-1] is convs[-1]
    assert sum(conv.stats for conv in convs) == norms
    # each normalised output is written once (skips and unpooled reads share it), pooling chains once each
    assert sum(p.normalize and p.rows is None for p in prepares) == norms
    # D8 -> D40 one pooling, D40 D -> D40 two, D40 D_2 -> D8 three: the chains are reduced in one launch
    assert sorted(p.rows.shape[1] for p in prepares if p.rows is not None) == [2, 4, 8]
    assert convs[0].segments[0].affine and convs[0].segments[0].source == NETWORK_INPUT
    for conv in convs:
        assert conv.weight.shape[0] == net.convs[0].size * sum(s.channels for s in conv.segments)
        assert all(s.rows is None or s.rows.shape[1] == 1 for s in conv.segments)    # only unpoolings
        if len(conv.segments) == 2:     # up block: the unpooled raw coarse output, then the normalised skip
            up, skip = (plan[s.source] for s in conv.segments)
            assert isinstance(up, FusedConv) and conv.segments[0].rows is not None
            assert isinstance(skip, Prepare) and skip.normalize and conv.segments[1].rows is None
    assert not convs[-1].stats and not convs[-2].stats


@pytest.mark.parametrize("pool,arch", CASES)
def test_folded_norms_give_the_plan_output_in_fewer_launches(pool, arch):
    """fold_norms: no Prepare is left that only normalises (each normed value is normalised by its readers on
    load), the poolings keep theirs, and the output is the unfolded plan's, aligned or not."""
    net, mesh, offset, scale, x = _case(pool, arch)
    plan, folded = fused_plan(net, mesh, 0.3), fused_plan(net, mesh, 0.3, fold_norms=True)
    prepares = lambda p: [launch for launch in p if isinstance(launch, Prepare)]  # noqa: E731
    assert not any(launch.rows is None for launch in prepares(folded))
    assert [launch.rows.shape for launch in prepares(folded)] == [launch.rows.shape for launch in prepares(plan)
                                                                  if launch.rows is not None]
    assert len(folded) == len(plan) - sum(launch.rows is None for launch in prepares(plan))
    readers = [s for launch in folded if isinstance(launch, FusedConv) for s in launch.segments if s.normalize]
    assert readers and all(folded[s.source].stats for s in readers)
    with torch.no_grad():
        expected = _reference(net, mesh, offset, scale, x)
        for steps in (folded, aligned_plan(folded, 16, 4)):
            got = run_plan_reference(steps, list(mesh.conv), x, offset, scale, pool == "max")
            assert _relative(got, expected) < FP32_TOLERANCE


def test_fused_network_refuses_what_it_cannot_run():
    net, mesh, offset, scale, x = _case("avg", ARCHS[0])
    decoder = build_network(NetworkSpec("U8 U U3", "RC7", in_channels=5, coarse_vertices=mesh.vertex_counts[3]))
    with pytest.raises(ValueError, match="encoder-decoder only"):
        fused_plan(decoder, mesh, 1.0)
    if os.environ.get("TRITON_INTERPRET") != "1":
        with pytest.raises(ValueError, match="runs on CUDA"):
            FusedNetwork(net, mesh, offset, scale, 0.3)(x)


@pytest.mark.parametrize("pool,arch", CASES)
def test_aligned_plan_gives_the_plan_output_and_aligned_widths(pool, arch):
    net, mesh, offset, scale, x = _case(pool, arch)
    plan = fused_plan(net, mesh, 0.3)
    aligned = aligned_plan(plan, 16, 4)
    with torch.no_grad():
        expected = run_plan_reference(plan, list(mesh.conv), x, offset, scale, net.pool_kind == "max")
        got = run_plan_reference(aligned, list(mesh.conv), x, offset, scale, net.pool_kind == "max")
    assert got.shape == expected.shape and _relative(got, expected) < FP32_TOLERANCE
    for old, new in zip(plan, aligned):
        width = (lambda launch: launch.weight.shape[1] if isinstance(launch, FusedConv) else launch.channels)
        assert width(new) == (width(old) if width(old) <= 4 or new is aligned[-1] else -(-width(old) // 16) * 16)
        if isinstance(new, FusedConv):
            inputs = [s.channels for s in new.segments]
            assert all(c % 16 == 0 or c <= 4 for s, c in zip(new.segments, inputs) if s.source != NETWORK_INPUT)
            assert new.weight.shape[0] == net.convs[0].size * sum(inputs)


def test_slot_products_summed_over_the_table_are_the_convolution():
    """The products-first form of a two-segment convolution (an unpooled coarse input and a skip), in PyTorch:
    each segment times its `slot_weights`, then each vertex's table neighbours' slot products summed."""
    net, mesh, offset, scale, x = _case("max", ARCHS[1])
    plan = fused_plan(net, mesh, 0.3)
    up = next(launch for launch in plan if isinstance(launch, FusedConv) and len(launch.segments) == 2)
    assert products_first(up) == (min(s.channels for s in up.segments) >= 16)
    table = mesh.conv[up.level]
    inputs = [torch.randn(2, int(s.rows.max()) + 1 if s.rows is not None else len(table), s.channels)
              for s in up.segments]
    through = [v if s.rows is None else v[:, torch.as_tensor(s.rows[:, 0])] for v, s in zip(inputs, up.segments)]
    expected = mesh_conv(torch.cat(through, dim=-1).double(), table, up.weight, up.bias)
    size, n_out = table.shape[1], up.weight.shape[1]
    got = up.bias.expand(2, len(table), n_out).clone()
    for values, segment, weights in zip(inputs, up.segments, slot_weights(up)):
        products = (values.double() @ weights).reshape(2, values.shape[1], size, n_out)
        rows = table.long() - 1                                           # -1: padding
        for slot in range(size):
            neighbour = rows[:, slot].clamp(min=0)
            if segment.rows is not None:
                neighbour = torch.as_tensor(segment.rows[:, 0])[neighbour]
            got += products[:, neighbour, slot] * (rows[:, slot] >= 0)[None, :, None]
    assert float((got - expected).abs().max()) < 1e-10 * float(expected.abs().max())


# The forms the kernels are checked in: every convolution a gather-GEMM; products first wherever they can be;
# and both again with the norms folded into their readers' loads (`fold_norms`); the whole plan as one persistent
# kernel (gathering), with and without the fold (one program in the interpreter, one per multiprocessor on CUDA).
VARIANTS = {"gather": dict(products=False), "products": dict(products=True), "fold": dict(fold_norms=True),
            "fold gather": dict(products=False, fold_norms=True), "fold products": dict(products=True, fold_norms=True),
            "persistent": dict(persistent=True), "fold persistent": dict(fold_norms=True, persistent=True)}
# Compiled kernels only: dependent launches (no such thing in the interpreter) change no arithmetic.
CUDA_VARIANTS = {**VARIANTS, "pdl": dict(pdl=True), "fold pdl": dict(fold_norms=True, pdl=True)}


def _kernel_errors(device: str, dtype: torch.dtype) -> dict[str, float]:
    """Per case and form (`VARIANTS`), the fused network's largest error relative to the plan's reference; with
    "fast" in the key, FastNetwork's at the same dtype (the bound bf16 is held to)."""
    errors = {}
    variants = CUDA_VARIANTS if device == "cuda" else VARIANTS
    for (pool, arch), variant in [(case, variant) for case in CASES for variant in variants]:
        net, mesh, offset, scale, x = _case(pool, arch)
        expected = _reference(net, mesh, offset, scale, x)
        fused = FusedNetwork(net, mesh, offset, scale, 0.3, dtype, **variants[variant]).to(device)
        forms = sorted(fused.forms.values())
        if variant.endswith("products") or variant.endswith("gather"):
            assert forms == (["few"] + ["products"] * (len(net.convs) - 1) if variant.endswith("products")
                             else ["gather"] * len(net.convs))
        elif variant.startswith("fold"):    # the rules': a few-channel convolution normalising what it gathers
            assert any(fused.forms[i] == "few" and launch.segments[0].normalize
                       for i, launch in enumerate(fused.plan) if isinstance(launch, FusedConv))
        normalised = [s.normalize for launch in fused.plan if isinstance(launch, FusedConv) for s in launch.segments]
        assert any(normalised) == variant.startswith("fold")
        with torch.no_grad():
            errors[f"{pool} {arch} {variant}"] = _relative(fused(x.to(device)), expected)
            single = fused(x[1:].to(device))            # a frame alone: the batch does not mix frames
            errors[f"{pool} {arch} {variant} alone"] = _relative(single, expected[1:])
            if dtype != torch.float32 and variant == "products":
                fast = FastNetwork(net, mesh, offset, scale, 0.3, dtype).to(device)
                errors[f"{pool} {arch} fast"] = _relative(fast(x.to(device)), expected)
    return errors


@pytest.mark.skipif(torch.cuda.is_available(), reason="where CUDA is, the kernels run as dependent launches")
def test_dependent_launches_are_refused_where_they_cannot_run():
    """No Hopper GPU with a compiling Triton here: asking for programmatic dependent launches is one
    clear error at construction, not a failure inside a kernel launch."""
    net, mesh, offset, scale, _ = _case("max", ARCHS[0])
    with pytest.raises(ValueError, match="pdl: needs a CUDA build of Triton"):
        FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16, pdl=True)
    assert FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16).pdl is False


def test_the_persistent_kernel_gathers_every_convolution_and_refuses_what_it_cannot_run():
    """One persistent launch has no cuBLAS products and no dependent launches: its convolutions are the rules'
    few-channel ones and gather-GEMMs otherwise, and asking for products or pdl with it is one clear error."""
    net, mesh, offset, scale, _ = _case("max", ARCHS[1])
    rules = FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16)
    persistent = FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16, persistent=True)
    assert "products" in rules.forms.values() and "products" not in persistent.forms.values()
    assert {i for i, form in persistent.forms.items() if form == "few"} == \
        {i for i, form in rules.forms.items() if form == "few"} and "gather" in persistent.forms.values()
    for option in (dict(products=True), dict(pdl=True)):
        with pytest.raises(ValueError, match="persistent: one launch"):
            FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16, persistent=True, **option)


def test_plan_phases_put_each_step_right_after_its_sources():
    """The persistent kernel's phases (one grid barrier each): every step once, after each of its sources, and as
    early as that allows - in phase 0 or right after one of its sources - so the unfolded plan's normalised
    copies for skip connections share a phase with the pooling that reads the same convolution."""
    net, mesh, offset, scale, _ = _case("max", ARCHS[1])
    for fold in (False, True):
        plan = FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16, fold_norms=fold, persistent=True).plan
        phases = plan_phases(plan)
        phase_of = {step: number for number, phase in enumerate(phases) for step in phase}
        assert sorted(phase_of) == list(range(len(plan))) and all(phases)
        for step, launch in enumerate(plan):
            sources = [launch.source] if isinstance(launch, Prepare) else [s.source for s in launch.segments]
            before = [phase_of[s] for s in sources if s != NETWORK_INPUT]
            assert all(phase < phase_of[step] for phase in before)
            assert phase_of[step] == (max(before) + 1 if before else 0)
        assert (len(phases) < len(plan)) == (not fold)


@pytest.mark.skipif(importlib.util.find_spec("triton") is None or torch.cuda.is_available(),
                    reason="needs Triton; where CUDA is, the test below runs the compiled kernels instead")
def test_triton_kernels_interpreted_on_the_cpu_match_the_plan():
    errors = interpreted_errors(__file__)
    print(errors)
    assert len(errors) == 2 * len(VARIANTS) * len(CASES) and max(errors.values()) < FP32_TOLERANCE


@pytest.mark.skipif(not torch.cuda.is_available() or importlib.util.find_spec("triton") is None,
                    reason="needs CUDA and Triton")
def test_triton_kernels_on_cuda_match_the_plan():
    errors = _kernel_errors("cuda", torch.float32)
    print(errors)
    assert max(errors.values()) < FP32_TOLERANCE
    errors = _kernel_errors("cuda", torch.bfloat16)
    print(errors)
    for pool, arch in CASES:        # bf16 hidden layers: no worse than the bf16 fast path on the same network
        bound = 2 * errors[f"{pool} {arch} fast"] + 1e-3
        assert all(errors[f"{pool} {arch} {variant}{alone}"] < bound
                   for variant in CUDA_VARIANTS for alone in ("", " alone"))


if __name__ == "__main__":      # the interpreted run of test_triton_kernels_interpreted_on_the_cpu_match_the_plan
    print(json.dumps(_kernel_errors("cpu", torch.float32)))
