"""The encoder-decoder as one fused kernel per convolution: what `FastNetwork` computes, in ~15 launches a frame.

`FastNetwork` runs ~150 small kernels a frame (a gather, a matmul, norm statistics, pool and unpool copies,
concatenations): on an H100 the frame is bound by launches and by the gathers' memory traffic, not by the
matmuls (docs/performance.md, "Deployment path"). Here every other step is folded into the convolution that
reads its result:

* **norm** -> the convolution producing the normalised tensor also sums each channel and its square over the
  vertices (its epilogue); the reader turns the sums into mean and 1/std and applies (x - mean) / std and the
  leaky ReLU as it loads (its prologue). The stored tensor stays the raw convolution output.
* **pool / unpool** -> index maps composed into each input segment's `rows` (V_level, P): the P source rows whose
  (prologue-applied) values are averaged or maxed; an unpooling is a 1-wide map, k poolings a 2^k-wide one.
* **concat** -> a convolution reads two segments (the unpooled coarse output and the saved skip), each with its
  own map and prologue, into consecutive weight rows.
* **input normalisation** -> the first convolution's prologue, (x - offset) / scale; the output scale is folded
  into the last convolution's weights.

The plan (`fused_plan`) is the network compiled to those convolutions; `run_plan_reference` executes it with
PyTorch operators on any device and is the specification the Triton kernel (model.triton_conv) is tested against;
`FusedNetwork` runs it on CUDA with that kernel. The variance is E[x^2] - E[x]^2 of fp32 sums (the only form
that a one-pass epilogue can accumulate), so results differ from the eager two-pass norm by rounding only
(tests/model/test_fused_network.py measures it).
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import torch
from torch import nn

from model.layers import LEAKY_SLOPE, NORM_EPS
from model.mesh_hierarchy import MeshHierarchy
from model.networks import EncoderDecoder

PROLOGUE_NONE, PROLOGUE_AFFINE, PROLOGUE_NORM = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class Segment:
    """A run of a fused convolution's input channels: `channels` of tensor `source` (-1: the network input,
    else the output of plan[source]) at each table vertex's `rows` (None: the vertex itself), reduced over the
    map's P columns by the network's pooling, after `prologue`."""

    source: int
    channels: int
    rows: np.ndarray | None
    prologue: int


@dataclasses.dataclass(frozen=True)
class FusedConv:
    """One launch: out = gather(segments at table) @ weight + bias, `stats` if a norm reads the output."""

    level: int
    segments: tuple[Segment, ...]
    weight: torch.Tensor        # (L * sum(channels), out), slot-major as model.layers.mesh_conv, fp64
    bias: torch.Tensor          # (out,), fp64
    stats: bool


@dataclasses.dataclass
class _Value:
    """What the step list holds between convolutions: rows of a stored tensor seen through a map and prologue."""

    source: int
    channels: int
    rows: np.ndarray | None = None
    prologue: int = PROLOGUE_NONE


def _compose(rows: np.ndarray | None, index: np.ndarray) -> np.ndarray:
    """The map of `index` (V_new,) or (V_new, K) applied after `rows` (V_old, P) -> (V_new, K * P)."""
    index = index.reshape(len(index), -1)
    if rows is None:
        return index
    return np.concatenate([rows[index[:, k]] for k in range(index.shape[1])], axis=1)


def fused_plan(net: EncoderDecoder, mesh: MeshHierarchy, output_scale: float) -> list[FusedConv]:
    """The encoder-decoder's steps as fused convolutions over `mesh` (the network input's prologue is the affine
    normalisation; its offset and scale are the executor's). Raises ValueError for a step it cannot fuse."""
    if not isinstance(net, EncoderDecoder):
        raise ValueError(f"fused inference runs the encoder-decoder only, got a {type(net).__name__}")
    net.check_mesh(mesh)
    pool = [t.cpu().numpy() for t in mesh.pool]
    unpool = [t.cpu().numpy() for t in mesh.unpool]
    plan: list[FusedConv] = []
    value: _Value | list[_Value] = _Value(-1, net.in_channels, prologue=PROLOGUE_AFFINE)
    skips: list[_Value] = []
    last = len(net.convs) - 1
    for step in net.steps:
        if step.op == "conv":
            segments = value if isinstance(value, list) else [value]
            conv = net.convs[step.index]
            scale = output_scale if step.index == last else 1.0
            plan.append(FusedConv(step.level, tuple(Segment(s.source, s.channels, s.rows, s.prologue)
                                                    for s in segments),
                                  conv.weight.detach().double().cpu() * scale,
                                  conv.bias.detach().double().cpu() * scale, stats=False))
            value = _Value(len(plan) - 1, conv.out_channels)
        elif step.op == "norm":
            if isinstance(value, list) or value.rows is not None or value.source < 0:
                raise ValueError("a norm must directly follow a convolution to be fused")
            plan[value.source] = dataclasses.replace(plan[value.source], stats=True)
            value = dataclasses.replace(value, prologue=PROLOGUE_NORM)
        elif step.op == "save":
            skips.append(value)
        elif step.op in ("pool", "unpool"):
            index = pool[step.level] if step.op == "pool" else unpool[step.level]
            value = dataclasses.replace(value, rows=_compose(value.rows, index))
        elif step.op == "concat":
            value = [value, skips.pop()]
        else:
            raise ValueError(f"no fused form of the step '{step.op}'")
    return plan


def _sums(x: torch.Tensor) -> torch.Tensor:
    """(B, 2, C) per-channel sums of x and x^2 over the vertices, in fp32: what the kernel's epilogue adds up."""
    wide = x.float()
    return torch.stack([wide.sum(dim=1), (wide * wide).sum(dim=1)], dim=1)


def norm_from_sums(sums: torch.Tensor, n_vertices: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean, 1/std) (B, C) of an instance norm from `_sums`."""
    mean = sums[:, 0] / n_vertices
    var = torch.clamp(sums[:, 1] / n_vertices - mean * mean, min=0.0)
    return mean, torch.rsqrt(var + NORM_EPS)


def run_plan_reference(plan: list[FusedConv], tables: list[torch.Tensor], x: torch.Tensor,
                       input_offset: torch.Tensor, input_scale: torch.Tensor, pool_max: bool) -> torch.Tensor:
    """Execute `plan` with PyTorch operators in fp64-free fp32: x (B, V_0, C_in) raw -> (B, V_0, out).
    `tables[l]` is level l's (V_l, L) convolution table with +1 ids."""
    outputs: list[torch.Tensor] = []
    sums: list[torch.Tensor | None] = []
    for conv in plan:
        parts = []
        for segment in conv.segments:
            source = x if segment.source < 0 else outputs[segment.source]
            values = source.float()
            if segment.prologue == PROLOGUE_AFFINE:
                values = (values - input_offset) / input_scale
            elif segment.prologue == PROLOGUE_NORM:
                mean, inv_std = norm_from_sums(sums[segment.source], source.shape[1])
                values = torch.nn.functional.leaky_relu((values - mean[:, None]) * inv_std[:, None], LEAKY_SLOPE)
            if segment.rows is not None:
                rows = torch.as_tensor(segment.rows, device=x.device)
                picked = values.index_select(1, rows.reshape(-1)).reshape(x.shape[0], *rows.shape, -1)
                values = picked.amax(dim=2) if pool_max else picked.mean(dim=2)
            parts.append(values)
        joined = torch.cat(parts, dim=-1)
        padded = torch.nn.functional.pad(joined, (0, 0, 1, 0))
        table = tables[conv.level]
        gathered = padded.index_select(1, table.reshape(-1)).reshape(x.shape[0], table.shape[0], -1)
        out = gathered @ conv.weight.float().to(x.device) + conv.bias.float().to(x.device)
        outputs.append(out)
        sums.append(_sums(out) if conv.stats else None)
    return outputs[-1]


class FusedNetwork(nn.Module):
    """`FastNetwork`'s function (raw features (B, V_0, C) in the level-0 order of `mesh` -> scaled displacement
    (B, V_0, out) fp32) as one Triton kernel per convolution, on CUDA. `dtype` is the hidden layers' storage
    and matmul type (bf16: fp32 accumulation and fp32 norm statistics); the first and last convolutions are
    fp32 in full precision, as FastNetwork's, since raw positions and the answer itself lose too much in bf16."""

    def __init__(self, net: EncoderDecoder, mesh: MeshHierarchy, input_offset: torch.Tensor,
                 input_scale: torch.Tensor, output_scale: float, dtype: torch.dtype = torch.float32):
        super().__init__()
        mesh = mesh.to("cpu")
        self.plan = fused_plan(net, mesh, output_scale)
        self.pool_max = net.pool_kind == "max"
        self.dtype = dtype
        self.vertex_counts = mesh.vertex_counts
        last = len(self.plan) - 1
        for level, table in enumerate(mesh.conv):
            self.register_buffer(f"table_{level}", table.to(torch.int32).contiguous())
        for index, conv in enumerate(self.plan):
            kind = torch.float32 if index in (0, last) else dtype
            self.register_buffer(f"weight_{index}", conv.weight.to(kind).contiguous())
            self.register_buffer(f"bias_{index}", conv.bias.float())
            for number, segment in enumerate(conv.segments):
                if segment.rows is not None:
                    self.register_buffer(f"rows_{index}_{number}",
                                         torch.as_tensor(segment.rows, dtype=torch.int32).contiguous())
        self.register_buffer("affine", torch.stack([input_offset.detach().float().cpu(),
                                                    1.0 / input_scale.detach().float().cpu()]))
        widths = [conv.weight.shape[1] if conv.stats else 0 for conv in self.plan]
        self.stats_offsets = np.concatenate([[0], np.cumsum(widths)]).tolist()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (x.is_cuda or os.environ.get("TRITON_INTERPRET") == "1"):
            raise ValueError("the fused network runs on CUDA (FastNetwork is the CPU path)")
        # Imported here: Triton comes with PyTorch's CUDA builds and is not a requirement of the CPU install.
        from model.triton_conv import SegmentArgs, SumsArgs, fused_conv
        batch, total = x.shape[0], self.stats_offsets[-1]
        # One buffer for every norm's sums, zeroed once a frame: one memset node in a captured graph.
        sums = torch.zeros(batch * 2 * total + 1, device=x.device, dtype=torch.float32)
        affine = self.affine.reshape(-1)
        outputs: list[torch.Tensor] = []
        last = len(self.plan) - 1
        for index, conv in enumerate(self.plan):
            segments = []
            for number, segment in enumerate(conv.segments):
                source = x.float().contiguous() if segment.source < 0 else outputs[segment.source]
                if segment.prologue == PROLOGUE_NORM:
                    par = (sums[self.stats_offsets[segment.source]:], 2 * total, total)
                else:
                    par = (affine, 0, segment.channels)
                segments.append(SegmentArgs(source, getattr(self, f"rows_{index}_{number}", None),
                                            segment.prologue, *par))
            weight = getattr(self, f"weight_{index}")
            out_dtype = torch.float32 if index >= last - 1 else weight.dtype
            target = SumsArgs(sums[self.stats_offsets[index]:], 2 * total, total) if conv.stats else None
            outputs.append(fused_conv(getattr(self, f"table_{conv.level}"), segments, weight,
                                      getattr(self, f"bias_{index}"), out_dtype, target, self.pool_max))
        return outputs[-1]
