"""One fused mesh convolution as a Triton kernel: gather through the table (and each segment's pool/unpool map),
the reader's prologue (input affine or instance norm + leaky ReLU), the matmul on tensor cores, the bias, and the
norm statistics of the output, in one launch (model.fused_network describes the plan it runs).

Each program computes a BLOCK_M x BLOCK_N tile of one frame's output. The A operand (vertices x gathered inputs)
never exists in memory: for each table slot and chunk of input channels the program loads the neighbours' rows
straight into registers, applies the prologue, and feeds `tl.dot`; the weights stream through in the same
slot-major order as model.layers.mesh_conv. The output tile's columns are summed (and squared) and added
atomically into the norm buffer, so the fp32 sums - and hence the last bits of later layers - depend on the
order the programs finish in: results are reproducible to rounding, not bit for bit.

Set TRITON_INTERPRET=1 before importing this module to run the kernel on the CPU with Triton's interpreter (the
tests do); there the configuration is fixed instead of tuned.
"""
from __future__ import annotations

import os
from typing import NamedTuple

import torch
import triton
import triton.language as tl

from model.layers import LEAKY_SLOPE, NORM_EPS

INTERPRETED = os.environ.get("TRITON_INTERPRET") == "1"


@triton.jit
def _segment_tile(src_ptr, rows_ptr, par_ptr, par_second, src_vertices, channels, entry, valid, cols,
                  P: tl.constexpr, MAPPED: tl.constexpr, PROLOGUE: tl.constexpr, POOL_MAX: tl.constexpr,
                  EPS: tl.constexpr, SLOPE: tl.constexpr):
    """(BLOCK_M, BLOCK_K) fp32 inputs of one segment: the table entries `entry` (0-based, `valid` where the
    table does not pad) seen through the map, channels `cols`; 0 at padding and past the last channel."""
    col_ok = cols < channels
    mask = valid[:, None] & col_ok[None, :]
    if PROLOGUE != 0:
        # par: PROLOGUE 1 = (offset, 1/scale) of the network input; 2 = the source's (sum, sum of squares).
        first = tl.load(par_ptr + cols, mask=col_ok, other=0.0)
        second = tl.load(par_ptr + par_second + cols, mask=col_ok, other=0.0)
        if PROLOGUE == 2:
            shift = first / src_vertices
            factor = 1.0 / tl.sqrt(tl.maximum(second / src_vertices - shift * shift, 0.0) + EPS)
        else:
            shift = first
            factor = second
    result = tl.zeros(mask.shape, dtype=tl.float32)
    for p in tl.static_range(P):
        if MAPPED:
            row = tl.load(rows_ptr + entry * P + p, mask=valid, other=0)
        else:
            row = entry
        x = tl.load(src_ptr + row[:, None].to(tl.int64) * channels + cols[None, :], mask=mask, other=0.0)
        x = x.to(tl.float32)
        if PROLOGUE != 0:
            x = (x - shift[None, :]) * factor[None, :]
        if PROLOGUE == 2:
            x = tl.where(x > 0, x, x * SLOPE)
        if p == 0:
            result = x
        elif POOL_MAX:
            result = tl.maximum(result, x)
        else:
            result = result + x
    if not POOL_MAX and P > 1:
        result = result * (1.0 / P)
    return tl.where(mask, result, 0.0)


@triton.jit
def _fused_conv_kernel(out_ptr, stats_ptr, stats_batch_stride, stats_second,
                       table_ptr, weight_ptr, bias_ptr, n_vertices, n_out,
                       src1_ptr, rows1_ptr, par1_ptr, par1_batch_stride, par1_second, src1_vertices, c1,
                       src2_ptr, rows2_ptr, par2_ptr, par2_batch_stride, par2_second, src2_vertices, c2,
                       L: tl.constexpr, P1: tl.constexpr, MAPPED1: tl.constexpr, PROLOGUE1: tl.constexpr,
                       P2: tl.constexpr, MAPPED2: tl.constexpr, PROLOGUE2: tl.constexpr, TWO: tl.constexpr,
                       POOL_MAX: tl.constexpr, STATS: tl.constexpr, IEEE: tl.constexpr,
                       EPS: tl.constexpr, SLOPE: tl.constexpr,
                       BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr, BLOCK_K: tl.constexpr):
    frame = tl.program_id(2).to(tl.int64)
    rows = tl.program_id(0) * BLOCK_M + tl.arange(0, BLOCK_M)
    outs = tl.program_id(1) * BLOCK_N + tl.arange(0, BLOCK_N)
    row_ok, out_ok = rows < n_vertices, outs < n_out
    src1 = src1_ptr + frame * src1_vertices * c1
    par1 = par1_ptr + frame * par1_batch_stride
    src2 = src2_ptr + frame * src2_vertices * c2
    par2 = par2_ptr + frame * par2_batch_stride
    width = c1 + c2
    acc = tl.zeros((BLOCK_M, BLOCK_N), dtype=tl.float32)
    for slot in range(L):
        entry = tl.load(table_ptr + rows * L + slot, mask=row_ok, other=0) - 1   # +1 ids: -1 is padding
        valid = entry >= 0
        entry = tl.maximum(entry, 0)
        for start in range(0, c1, BLOCK_K):
            cols = start + tl.arange(0, BLOCK_K)
            a = _segment_tile(src1, rows1_ptr, par1, par1_second, src1_vertices, c1, entry, valid, cols,
                              P1, MAPPED1, PROLOGUE1, POOL_MAX, EPS, SLOPE)
            w = tl.load(weight_ptr + (slot * width + cols)[:, None].to(tl.int64) * n_out + outs[None, :],
                        mask=(cols < c1)[:, None] & out_ok[None, :], other=0.0)
            if IEEE:
                acc = tl.dot(a, w, acc, input_precision="ieee")
            else:
                acc = tl.dot(a.to(w.dtype), w, acc)
        if TWO:
            for start in range(0, c2, BLOCK_K):
                cols = start + tl.arange(0, BLOCK_K)
                a = _segment_tile(src2, rows2_ptr, par2, par2_second, src2_vertices, c2, entry, valid, cols,
                                  P2, MAPPED2, PROLOGUE2, POOL_MAX, EPS, SLOPE)
                w = tl.load(weight_ptr + (slot * width + c1 + cols)[:, None].to(tl.int64) * n_out + outs[None, :],
                            mask=(cols < c2)[:, None] & out_ok[None, :], other=0.0)
                if IEEE:
                    acc = tl.dot(a, w, acc, input_precision="ieee")
                else:
                    acc = tl.dot(a.to(w.dtype), w, acc)
    acc += tl.load(bias_ptr + outs, mask=out_ok, other=0.0)[None, :]
    keep = row_ok[:, None] & out_ok[None, :]
    tl.store(out_ptr + frame * n_vertices * n_out + rows[:, None].to(tl.int64) * n_out + outs[None, :],
             acc.to(out_ptr.dtype.element_ty), mask=keep)
    if STATS:
        kept = tl.where(keep, acc, 0.0)
        stats = stats_ptr + frame * stats_batch_stride
        tl.atomic_add(stats + outs, tl.sum(kept, axis=0), mask=out_ok)
        tl.atomic_add(stats + stats_second + outs, tl.sum(kept * kept, axis=0), mask=out_ok)


_CONFIGS = [triton.Config({"BLOCK_M": m, "BLOCK_N": n, "BLOCK_K": k}, num_warps=w, num_stages=s)
            for m, n, k, w, s in ((32, 64, 32, 4, 2), (64, 64, 32, 4, 3), (64, 128, 32, 4, 3),
                                  (128, 64, 32, 4, 3), (128, 128, 32, 8, 3), (64, 256, 32, 8, 3),
                                  (64, 64, 64, 4, 3), (128, 128, 64, 8, 2))]


def _small_problems_untuned(configs, named_args, **_):
    """A convolution of under ~64 output tiles (the coarse levels, the tests' meshes) gets the smallest tile
    untimed: tuning it would cost seconds of compiling for microseconds."""
    if named_args["n_vertices"] * named_args["n_out"] < 64 * 64 * 64:
        return configs[:1]
    return configs


# The sums the kernel adds to are restored after each timing run, so tuning leaves the frame's result intact.
_tuned_kernel = triton.autotune(_CONFIGS, key=["n_vertices", "n_out", "c1", "c2"],
                                prune_configs_by={"early_config_prune": _small_problems_untuned},
                                restore_value=["stats_ptr"])(_fused_conv_kernel)
_FIXED = {"BLOCK_M": 16, "BLOCK_N": 16, "BLOCK_K": 16}


class SegmentArgs(NamedTuple):
    """One input segment of a launch (model.fused_network.Segment, resolved to tensors)."""

    source: torch.Tensor            # (B, V_src, C) contiguous
    rows: torch.Tensor | None       # (V, P) int32 source rows of each table vertex; None: the vertex itself
    prologue: int
    par: torch.Tensor               # fp32, flat: the prologue's two rows at [0, C) and [second, second + C)
    par_batch_stride: int           # elements between frames' rows (0: shared by all frames)
    par_second: int


class SumsArgs(NamedTuple):
    """Where a launch adds its output's per-channel sums: buffer[frame * batch_stride + c] and
    buffer[frame * batch_stride + second + c] (a flat fp32 view starting at this output's first column)."""

    buffer: torch.Tensor
    batch_stride: int
    second: int


def _segment_args(segment: SegmentArgs, placeholder: torch.Tensor) -> list:
    return [segment.source, placeholder if segment.rows is None else segment.rows, segment.par,
            segment.par_batch_stride, segment.par_second, segment.source.shape[1], segment.source.shape[2]]


def fused_conv(table: torch.Tensor, segments: list[SegmentArgs], weight: torch.Tensor, bias: torch.Tensor,
               out_dtype: torch.dtype, sums: SumsArgs | None, pool_max: bool) -> torch.Tensor:
    """Launch one fused convolution: table (V, L) int32 +1 ids, one or two segments whose channels fill the
    weight's (L * sum C, N) rows slot by slot, bias (N,) fp32. Returns (B, V, N) of `out_dtype`."""
    if not 1 <= len(segments) <= 2:
        raise ValueError(f"a fused convolution reads one or two segments, got {len(segments)}")
    n_vertices, size = table.shape
    n_out = weight.shape[1]
    batch = segments[0].source.shape[0]
    out = torch.empty(batch, n_vertices, n_out, device=table.device, dtype=out_dtype)
    first = segments[0]
    second = segments[1] if len(segments) == 2 else first
    args = _segment_args(first, table) + _segment_args(second, table)
    if len(segments) == 1:
        args[-1] = 0                # c2 = 0: the placeholder second segment's loop never runs
    sums_args = (sums.buffer, sums.batch_stride, sums.second) if sums is not None else (bias, 0, 0)
    constants = dict(L=size, P1=1 if first.rows is None else first.rows.shape[1], MAPPED1=first.rows is not None,
                     PROLOGUE1=first.prologue, P2=1 if second.rows is None else second.rows.shape[1],
                     MAPPED2=second.rows is not None, PROLOGUE2=second.prologue, TWO=len(segments) == 2,
                     POOL_MAX=pool_max, STATS=sums is not None, IEEE=weight.dtype == torch.float32,
                     EPS=NORM_EPS, SLOPE=LEAKY_SLOPE)
    launch_args = (out, *sums_args, table, weight, bias, n_vertices, n_out, *args)
    if INTERPRETED:
        grid = (triton.cdiv(n_vertices, _FIXED["BLOCK_M"]), triton.cdiv(n_out, _FIXED["BLOCK_N"]), batch)
        _fused_conv_kernel[grid](*launch_args, **constants, **_FIXED)
    else:
        grid = lambda meta: (triton.cdiv(n_vertices, meta["BLOCK_M"]),  # noqa: E731
                             triton.cdiv(n_out, meta["BLOCK_N"]), batch)
        _tuned_kernel[grid](*launch_args, **constants)
    return out
