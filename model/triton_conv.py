"""The fused network's Triton kernels (model.fused_network describes the plan that launches them).

* `gather_sum`: the second half of a products-first convolution - each vertex sums its table neighbours' rows of
  the slot products P = x @ [W_0 ... W_{L-1}] (cuBLAS made them), slot k's block for neighbour k, through an
  unpooling map where the segment is one; bias and norm sums as below. The slots are unrolled so their gathers
  are all in flight at once: a memory-bound pass.
* `few_channel_conv`: a convolution of a handful of input channels (the raw features, with their affine) as one
  (rows x slots) gather per channel and an fp32 FMA dot: no tensor-core tile padding 3 channels to 16.

* `fused_conv`: one mesh convolution as a gather-GEMM. Each program computes a BLOCK_M x BLOCK_N tile of one
  frame's output; for each (table slot, chunk of input channels) it loads the neighbours' rows - through the
  segment's unpooling map, if any - straight into registers and feeds `tl.dot`, so the (V, L * C) gathered
  matrix never exists in memory; the weights stream through in model.layers.mesh_conv's slot-major order. The
  table rows (and the unpooling map) of a program's vertices are loaded once, into registers, and the loop over
  (slot, chunk) is one flat loop, so no load in it waits on another and Triton software-pipelines it. fp32
  weights (a full-precision convolution of many channels) multiply as three tf32 products, fp32-accurate. The
  epilogue adds the bias and, for a norm, the output's per-channel sums and sums of squares, atomically: the
  fp32 sums, and hence later layers' last bits, depend on the order the programs finish in (reproducible to
  rounding, not bit for bit).
* `prepare`: instance norm + leaky ReLU from those sums, and/or a pooling chain (mean or max over P rows), once
  per value instead of once per gather.
* `normed_products`: with the norms folded into their readers (FusedNetwork's `fold_norms`), a products-first
  convolution's products of a normed value: a dense matmul whose prologue applies the norm and leaky ReLU to each
  tile it loads, in place of `prepare` + cuBLAS. `fused_conv` and `few_channel_conv` likewise normalise what they
  gather (NORM).

Each launcher is a custom operator, `torch.library.triton_op` (learned_cloth::<name>), its kernels launched through
`wrap_triton`: eager calls run them as before, and `torch.export` keeps each as one operator of the program, which
an export on CUDA ships with a copy of this module that defines them (deploy/export.py: keep it importing only
torch, Triton and the package's other modules, as its export checks). The
operators are functional: each allocates and returns its output and, for a norm, that output's per-channel sums
(B, 2, N) fp32, [b, 0] the sums and [b, 1] the sums of squares, which `prepare` reads.

With `pdl` (Hopper and later, a Triton that has it) each kernel is launched as a programmatic dependent launch:
it may start while the kernel before it runs, and waits for that kernel's results (`gdc_wait`) before it reads
anything, after letting the next one start (`gdc_launch_dependents`); a small network's frame is a chain of ~40
such few-microsecond kernels, whose launch gaps this overlaps. The arithmetic is unchanged.

Set TRITON_INTERPRET=1 before importing this module to run the kernels on the CPU with Triton's interpreter (the
tests do); there the tile sizes are fixed instead of tuned, and there is no dependent launch.
"""
from __future__ import annotations

import os

import torch
import triton
import triton.language as tl
from torch.library import triton_op, wrap_triton

from model.layers import LEAKY_SLOPE, NORM_EPS

INTERPRETED = os.environ.get("TRITON_INTERPRET") == "1"

try:        # Triton's grid dependency control (programmatic dependent launch), where this Triton has it
    from triton.language.extra.cuda import gdc_launch_dependents, gdc_wait
    PDL_SUPPORTED = not INTERPRETED
except ImportError:
    PDL_SUPPORTED = False

    @triton.jit
    def gdc_wait():     # never called: PDL is refused without the real one (a name for the dead branch below)
        pass

    @triton.jit
    def gdc_launch_dependents():
        pass


NAMESPACE = "learned_cloth"      # the operators' namespace: torch.ops.learned_cloth.<launcher>


@triton.jit
def _slot_rows(table_ptr, rows, row_ok, L: tl.constexpr, SLOTS: tl.constexpr):
    """(BLOCK_M, SLOTS) 0-based table entries of `rows` and where they are real (not padding or past L): loaded
    once per program, so no load in the main loop waits on another."""
    slots = tl.arange(0, SLOTS)
    inside = row_ok[:, None] & (slots[None, :] < L)
    entry = tl.load(table_ptr + rows[:, None] * L + slots[None, :], mask=inside, other=0) - 1   # +1 ids
    return tl.maximum(entry, 0), entry >= 0


@triton.jit
def _tile(n_rows, n_cols, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr, PDL: tl.constexpr):
    """A program's frame (grid axis 2), its BLOCK_M rows and BLOCK_N columns, and which of them exist; with PDL,
    first the wait for the kernel before (whose output every kernel here reads) and the next kernel's go-ahead."""
    if PDL:
        gdc_wait()
        gdc_launch_dependents()
    rows = tl.program_id(0) * BLOCK_M + tl.arange(0, BLOCK_M)
    cols = tl.program_id(1) * BLOCK_N + tl.arange(0, BLOCK_N)
    return tl.program_id(2).to(tl.int64), rows, cols, rows < n_rows, cols < n_cols


@triton.jit
def _norm_stats(sums_ptr, cols, col_ok, channels, n_src, EPS: tl.constexpr):
    """An instance norm's mean and 1/std of channels `cols` from a frame's sums (sums_ptr: its (2, channels),
    the sums then the sums of squares) over `n_src` vertices."""
    mean = tl.load(sums_ptr + cols, mask=col_ok, other=0.0) / n_src
    squares = tl.load(sums_ptr + channels + cols, mask=col_ok, other=0.0) / n_src
    return mean, 1.0 / tl.sqrt(tl.maximum(squares - mean * mean, 0.0) + EPS)


@triton.jit
def _norm_on_load(x, sums_ptr, cols, col_ok, mask, channels, n_src, EPS: tl.constexpr, SLOPE: tl.constexpr):
    """Instance norm (mean and 1/std from the frame's sums of the source, `n_src` vertices) + leaky ReLU of the
    loaded (rows, cols) values, in fp32; 0 where `mask` is off (padding slots)."""
    mean, factor = _norm_stats(sums_ptr, cols, col_ok, channels, n_src, EPS)
    x = (x.to(tl.float32) - mean[None, :]) * factor[None, :]
    return tl.where(mask, tl.where(x > 0, x, x * SLOPE), 0.0)


@triton.jit
def _dot_segment(acc, src_ptr, entries, valid, weight_ptr, affine_ptr, norm_ptr, n_src, outs, out_ok, channels,
                 row_offset, width, n_out, L: tl.constexpr, SLOTS: tl.constexpr, AFFINE: tl.constexpr,
                 NORM: tl.constexpr, PRECISE: tl.constexpr, BLOCK_K: tl.constexpr, EPS: tl.constexpr,
                 SLOPE: tl.constexpr):
    """acc + this segment's gathered inputs @ its weight rows (row_offset within each slot's `width`). The loop
    over (slot, channel chunk) is flat and its gather addresses come from registers, so Triton pipelines it.
    NORM: the inputs normalised on load from the source's sums at `norm_ptr` (this frame's (2, channels))."""
    chunks = tl.cdiv(channels, BLOCK_K)
    slots = tl.arange(0, SLOTS)
    for step in range(L * chunks):
        slot = step // chunks
        cols = (step - slot * chunks) * BLOCK_K + tl.arange(0, BLOCK_K)
        col_ok = cols < channels
        pick = slots[None, :] == slot                       # this slot's column of the register tiles
        entry = tl.sum(tl.where(pick, entries, 0), axis=1).to(tl.int64)
        real = tl.sum(tl.where(pick & valid, 1, 0), axis=1) > 0
        mask = real[:, None] & col_ok[None, :]
        a = tl.load(src_ptr + entry[:, None] * channels + cols[None, :], mask=mask, other=0.0)
        if AFFINE:
            shift = tl.load(affine_ptr + cols, mask=col_ok, other=0.0)
            factor = tl.load(affine_ptr + channels + cols, mask=col_ok, other=0.0)
            a = tl.where(mask, (a.to(tl.float32) - shift[None, :]) * factor[None, :], 0.0)
        if NORM:
            a = _norm_on_load(a, norm_ptr, cols, col_ok, mask, channels, n_src, EPS, SLOPE)
        w = tl.load(weight_ptr + (slot * width + row_offset + cols)[:, None].to(tl.int64) * n_out + outs[None, :],
                    mask=col_ok[:, None] & out_ok[None, :], other=0.0)
        if PRECISE:     # three tf32 products: fp32 accuracy on tensor cores
            acc = tl.dot(a.to(tl.float32), w, acc, input_precision="tf32x3")
        else:
            acc = tl.dot(a.to(w.dtype), w, acc)
    return acc


@triton.jit
def _conv_kernel(out_ptr, sums_ptr, sums_batch_stride, sums_second, table_ptr, weight_ptr, bias_ptr, affine_ptr,
                 n_vertices, n_out, src1_ptr, map1_ptr, src1_vertices, c1, src2_ptr, map2_ptr, src2_vertices, c2,
                 norm1_ptr, norm2_ptr, L: tl.constexpr, SLOTS: tl.constexpr, MAPPED1: tl.constexpr,
                 MAPPED2: tl.constexpr, TWO: tl.constexpr, AFFINE: tl.constexpr, NORM1: tl.constexpr,
                 NORM2: tl.constexpr, STATS: tl.constexpr, PRECISE: tl.constexpr, BLOCK_K: tl.constexpr,
                 EPS: tl.constexpr, SLOPE: tl.constexpr, PDL: tl.constexpr, BLOCK_M: tl.constexpr,
                 BLOCK_N: tl.constexpr):
    frame, rows, outs, row_ok, out_ok = _tile(n_vertices, n_out, BLOCK_M, BLOCK_N, PDL)
    _conv_tile(rows, outs, row_ok, out_ok, out_ptr + frame * n_vertices * n_out, sums_ptr + frame * sums_batch_stride,
               sums_second, table_ptr, weight_ptr, bias_ptr, affine_ptr, n_out,
               src1_ptr + frame * src1_vertices * c1, map1_ptr, src1_vertices, c1,
               src2_ptr + frame * src2_vertices * c2, map2_ptr, src2_vertices, c2,
               norm1_ptr + frame * 2 * c1, norm2_ptr + frame * 2 * c2, L, SLOTS, MAPPED1, MAPPED2, TWO, AFFINE,
               NORM1, NORM2, STATS, PRECISE, BLOCK_M, BLOCK_N, BLOCK_K, EPS, SLOPE)


@triton.jit
def _conv_tile(rows, outs, row_ok, out_ok, out, sums, sums_second, table_ptr, weight_ptr, bias_ptr, affine_ptr,
               n_out, src1, map1_ptr, src1_vertices, c1, src2, map2_ptr, src2_vertices, c2, norm1, norm2,
               L: tl.constexpr, SLOTS: tl.constexpr, MAPPED1: tl.constexpr, MAPPED2: tl.constexpr,
               TWO: tl.constexpr, AFFINE: tl.constexpr, NORM1: tl.constexpr, NORM2: tl.constexpr,
               STATS: tl.constexpr, PRECISE: tl.constexpr, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr,
               BLOCK_K: tl.constexpr, EPS: tl.constexpr, SLOPE: tl.constexpr):
    """`fused_conv`'s (BLOCK_M, BLOCK_N) output tile of one frame (out, sums, src and norm pointers at that
    frame's data): the kernel's body, which model.persistent_network's kernel calls too."""
    entries, valid = _slot_rows(table_ptr, rows, row_ok, L, SLOTS)
    width = c1 + c2
    acc = tl.zeros((BLOCK_M, BLOCK_N), dtype=tl.float32)
    mapped = entries
    if MAPPED1:                                             # an unpooling: the coarse vertex of each neighbour
        mapped = tl.load(map1_ptr + entries, mask=valid, other=0)
    acc = _dot_segment(acc, src1, mapped, valid, weight_ptr, affine_ptr, norm1, src1_vertices, outs, out_ok, c1, 0,
                       width, n_out, L, SLOTS, AFFINE, NORM1, PRECISE, BLOCK_K, EPS, SLOPE)
    if TWO:
        mapped = entries
        if MAPPED2:
            mapped = tl.load(map2_ptr + entries, mask=valid, other=0)
        acc = _dot_segment(acc, src2, mapped, valid, weight_ptr, affine_ptr, norm2, src2_vertices, outs, out_ok, c2,
                           c1, width, n_out, L, SLOTS, False, NORM2, PRECISE, BLOCK_K, EPS, SLOPE)
    _finish(acc, out, sums, sums_second, bias_ptr, rows, row_ok, outs, out_ok, n_out, STATS)


@triton.jit
def _finish(acc, out, sums, sums_second, bias_ptr, rows, row_ok, outs, out_ok, n_out, STATS: tl.constexpr):
    """A convolution's epilogue: + bias, stored in the output's dtype, and for a norm the fp32 per-channel sums
    of the tile and of its square added to the frame's (atomics; `out`, `sums`: the frame's)."""
    acc += tl.load(bias_ptr + outs, mask=out_ok, other=0.0)[None, :]
    keep = row_ok[:, None] & out_ok[None, :]
    tl.store(out + rows[:, None].to(tl.int64) * n_out + outs[None, :], acc.to(out.dtype.element_ty), mask=keep)
    if STATS:
        kept = tl.where(keep, acc, 0.0)
        tl.atomic_add(sums + outs, tl.sum(kept, axis=0), mask=out_ok)
        tl.atomic_add(sums + sums_second + outs, tl.sum(kept * kept, axis=0), mask=out_ok)


@triton.jit
def _add_products(acc, products_ptr, map_ptr, entry, valid, slot, outs, mask, n_out, MAPPED: tl.constexpr,
                  L: tl.constexpr):
    """acc + each row's table neighbour's (through the unpooling map) slot-`slot` product row."""
    if MAPPED:
        entry = tl.load(map_ptr + entry, mask=valid, other=0)
    offsets = entry[:, None].to(tl.int64) * (L * n_out) + slot * n_out + outs[None, :]
    return acc + tl.load(products_ptr + offsets, mask=mask, other=0.0).to(tl.float32)


@triton.jit
def _gather_sum_kernel(out_ptr, sums_ptr, sums_batch_stride, sums_second, table_ptr, bias_ptr, n_vertices, n_out,
                       src1_ptr, map1_ptr, src1_vertices, src2_ptr, map2_ptr, src2_vertices,
                       L: tl.constexpr, MAPPED1: tl.constexpr, MAPPED2: tl.constexpr, TWO: tl.constexpr,
                       STATS: tl.constexpr, PDL: tl.constexpr, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr):
    frame, rows, outs, row_ok, out_ok = _tile(n_vertices, n_out, BLOCK_M, BLOCK_N, PDL)
    src1 = src1_ptr + frame * src1_vertices * L * n_out
    src2 = src2_ptr + frame * src2_vertices * L * n_out
    acc = tl.zeros((BLOCK_M, BLOCK_N), dtype=tl.float32)
    for slot in tl.static_range(L):     # unrolled: the slots' gathers are independent and overlap
        entry = tl.load(table_ptr + rows * L + slot, mask=row_ok, other=0) - 1     # +1 ids, 0 = padding
        valid = entry >= 0
        entry = tl.maximum(entry, 0)
        mask = valid[:, None] & out_ok[None, :]
        acc = _add_products(acc, src1, map1_ptr, entry, valid, slot, outs, mask, n_out, MAPPED1, L)
        if TWO:
            acc = _add_products(acc, src2, map2_ptr, entry, valid, slot, outs, mask, n_out, MAPPED2, L)
    _finish(acc, out_ptr + frame * n_vertices * n_out, sums_ptr + frame * sums_batch_stride, sums_second, bias_ptr,
            rows, row_ok, outs, out_ok, n_out, STATS)


@triton.jit
def _few_channel_kernel(out_ptr, sums_ptr, sums_batch_stride, sums_second, table_ptr, weight_ptr, bias_ptr,
                        affine_ptr, norm_ptr, n_vertices, n_out, src_ptr, map_ptr, src_vertices, C: tl.constexpr,
                        L: tl.constexpr, SLOTS: tl.constexpr, MAPPED: tl.constexpr, AFFINE: tl.constexpr,
                        NORM: tl.constexpr, STATS: tl.constexpr, EPS: tl.constexpr, SLOPE: tl.constexpr,
                        PDL: tl.constexpr, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr):
    frame, rows, outs, row_ok, out_ok = _tile(n_vertices, n_out, BLOCK_M, BLOCK_N, PDL)
    _few_channel_tile(rows, outs, row_ok, out_ok, out_ptr + frame * n_vertices * n_out,
                      sums_ptr + frame * sums_batch_stride, sums_second, table_ptr, weight_ptr, bias_ptr, affine_ptr,
                      norm_ptr + frame * 2 * C, n_out, src_ptr + frame * src_vertices * C, map_ptr, src_vertices, C,
                      L, SLOTS, MAPPED, AFFINE, NORM, STATS, BLOCK_M, BLOCK_N, EPS, SLOPE)


@triton.jit
def _few_channel_tile(rows, outs, row_ok, out_ok, out, sums, sums_second, table_ptr, weight_ptr, bias_ptr,
                      affine_ptr, norm, n_out, src, map_ptr, src_vertices, C: tl.constexpr, L: tl.constexpr,
                      SLOTS: tl.constexpr, MAPPED: tl.constexpr, AFFINE: tl.constexpr, NORM: tl.constexpr,
                      STATS: tl.constexpr, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr, EPS: tl.constexpr,
                      SLOPE: tl.constexpr):
    """`few_channel_conv`'s output tile of one frame (pointers at that frame's data), as `_conv_tile`."""
    entries, valid = _slot_rows(table_ptr, rows, row_ok, L, SLOTS)
    if MAPPED:
        entries = tl.load(map_ptr + entries, mask=valid, other=0)
    slots = tl.arange(0, SLOTS)
    acc = tl.zeros((BLOCK_M, BLOCK_N), dtype=tl.float32)
    # Per channel, every slot's value of the tile's rows in one (BLOCK_M, SLOTS) gather - C gathers in all, none
    # waiting on another - times that channel's (SLOTS, BLOCK_N) weights as an fp32 FMA dot ("ieee": exact).
    for c in tl.static_range(C):
        x = tl.load(src + entries.to(tl.int64) * C + c, mask=valid, other=0.0).to(tl.float32)
        if AFFINE:
            x = tl.where(valid, (x - tl.load(affine_ptr + c)) * tl.load(affine_ptr + C + c), 0.0)
        if NORM:
            mean, factor = _norm_stats(norm, c, True, C, src_vertices, EPS)
            x = (x - mean) * factor
            x = tl.where(valid, tl.where(x > 0, x, x * SLOPE), 0.0)
        w = tl.load(weight_ptr + (slots[:, None] * C + c) * n_out + outs[None, :],
                    mask=(slots[:, None] < L) & out_ok[None, :], other=0.0).to(tl.float32)
        acc = tl.dot(x, w, acc, input_precision="ieee")
    _finish(acc, out, sums, sums_second, bias_ptr, rows, row_ok, outs, out_ok, n_out, STATS)


@triton.jit
def _prepare_kernel(out_ptr, src_ptr, map_ptr, sums_ptr, sums_batch_stride, n_rows, src_vertices,
                    channels, P: tl.constexpr, MAPPED: tl.constexpr, NORMALIZE: tl.constexpr,
                    POOL_MAX: tl.constexpr, EPS: tl.constexpr, SLOPE: tl.constexpr,
                    PDL: tl.constexpr, BLOCK_M: tl.constexpr, BLOCK_C: tl.constexpr):
    frame, rows, cols, row_ok, col_ok = _tile(n_rows, channels, BLOCK_M, BLOCK_C, PDL)
    _prepare_tile(rows, cols, row_ok, col_ok, out_ptr + frame * n_rows * channels,
                  src_ptr + frame * src_vertices * channels, map_ptr, sums_ptr + frame * sums_batch_stride,
                  src_vertices, channels, P, MAPPED, NORMALIZE, POOL_MAX, BLOCK_M, BLOCK_C, EPS, SLOPE)


@triton.jit
def _prepare_tile(rows, cols, row_ok, col_ok, out, src, map_ptr, sums, src_vertices, channels, P: tl.constexpr,
                  MAPPED: tl.constexpr, NORMALIZE: tl.constexpr, POOL_MAX: tl.constexpr, BLOCK_M: tl.constexpr,
                  BLOCK_C: tl.constexpr, EPS: tl.constexpr, SLOPE: tl.constexpr):
    """`prepare`'s tile of one frame (pointers at that frame's data), as `_conv_tile`."""
    mask = row_ok[:, None] & col_ok[None, :]
    if NORMALIZE:
        mean, factor = _norm_stats(sums, cols, col_ok, channels, src_vertices, EPS)
    result = tl.zeros((BLOCK_M, BLOCK_C), dtype=tl.float32)
    paths = tl.arange(0, P)
    if MAPPED:      # all P source rows at once (P is a power of two), so the P gathers below overlap
        sources = tl.load(map_ptr + rows[:, None] * P + paths[None, :], mask=row_ok[:, None], other=0)
    for p in tl.static_range(P):
        if MAPPED:
            source_rows = tl.sum(tl.where(paths[None, :] == p, sources, 0), axis=1)
        else:
            source_rows = rows
        x = tl.load(src + source_rows[:, None].to(tl.int64) * channels + cols[None, :], mask=mask, other=0.0)
        x = x.to(tl.float32)
        if NORMALIZE:
            x = (x - mean[None, :]) * factor[None, :]
            x = tl.where(x > 0, x, x * SLOPE)
        if p == 0:
            result = x
        elif POOL_MAX:
            result = tl.maximum(result, x)
        else:
            result = result + x
    if not POOL_MAX and P > 1:
        result = result * (1.0 / P)
    tl.store(out + rows[:, None].to(tl.int64) * channels + cols[None, :], result.to(out.dtype.element_ty), mask=mask)


@triton.jit
def _normed_products_kernel(out_ptr, src_ptr, sums_ptr, weight_ptr, n_rows, channels, n_cols,
                            PRECISE: tl.constexpr, EPS: tl.constexpr, SLOPE: tl.constexpr, PDL: tl.constexpr,
                            BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr, BLOCK_K: tl.constexpr):
    frame, rows, outs, row_ok, out_ok = _tile(n_rows, n_cols, BLOCK_M, BLOCK_N, PDL)
    src = src_ptr + frame * n_rows * channels
    sums = sums_ptr + frame * 2 * channels
    acc = tl.zeros((BLOCK_M, BLOCK_N), dtype=tl.float32)
    for start in range(0, channels, BLOCK_K):
        cols = start + tl.arange(0, BLOCK_K)
        col_ok = cols < channels
        mask = row_ok[:, None] & col_ok[None, :]
        a = tl.load(src + rows[:, None].to(tl.int64) * channels + cols[None, :], mask=mask, other=0.0)
        a = _norm_on_load(a, sums, cols, col_ok, mask, channels, n_rows, EPS, SLOPE)
        w = tl.load(weight_ptr + cols[:, None] * n_cols + outs[None, :], mask=col_ok[:, None] & out_ok[None, :],
                    other=0.0)
        if PRECISE:
            acc = tl.dot(a, w, acc, input_precision="tf32x3")
        else:
            acc = tl.dot(a.to(w.dtype), w, acc)
    tl.store(out_ptr + frame * n_rows * n_cols + rows[:, None].to(tl.int64) * n_cols + outs[None, :],
             acc.to(out_ptr.dtype.element_ty), mask=row_ok[:, None] & out_ok[None, :])


# Few configurations: each costs seconds of compiling per distinct convolution on the first call.
_CONFIGS = [triton.Config({"BLOCK_M": m, "BLOCK_N": n}, num_warps=w, num_stages=s)
            for m, n, w, s in ((64, 64, 4, 3), (64, 128, 4, 3), (128, 64, 4, 3), (128, 128, 8, 3))]
# Coarse levels have few rows: small tiles keep more SMs busy.
_SMALL_CONFIGS = [triton.Config({"BLOCK_M": m, "BLOCK_N": n}, num_warps=4, num_stages=3)
                  for m, n in ((16, 64), (32, 32), (32, 64))]


def _configs_for(configs, named_args, **_):
    """The small tiles for a convolution of under ~64 large output tiles, the large ones otherwise."""
    if named_args["n_vertices"] * named_args["n_out"] < 64 * 64 * 64:
        return _SMALL_CONFIGS
    return configs


# The sums the kernel adds to are restored after each timing run, so tuning leaves the frame's result intact.
_tuned_conv = triton.autotune(_CONFIGS, key=["n_vertices", "n_out", "c1", "c2"],
                              prune_configs_by={"early_config_prune": _configs_for},
                              restore_value=["sums_ptr"])(_conv_kernel)
_FIXED = {"BLOCK_M": 16, "BLOCK_N": 16}
_tuned_products = triton.autotune(_CONFIGS, key=["n_rows", "channels", "n_cols"])(_normed_products_kernel)


@triton_op(f"{NAMESPACE}::fused_conv", mutates_args=())
def fused_conv(table: torch.Tensor, src1: torch.Tensor, map1: torch.Tensor | None, src2: torch.Tensor | None,
               map2: torch.Tensor | None, affine: torch.Tensor | None, norm1: torch.Tensor | None,
               norm2: torch.Tensor | None, weight: torch.Tensor, bias: torch.Tensor, out_dtype: torch.dtype,
               stats: bool, pdl: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """One convolution: table (V, L) int32 +1 ids; one or two segments (source (B, V_src, C) contiguous, map
    (V_src_table, 1) int32 or None) filling the weight's (L * sum C, N) rows slot by slot; `affine` (2 C_1,)
    = (offset, 1/scale) applied to the first segment on load, or None; `norm1`/`norm2`: the segment's source's
    sums (B, 2, C) to normalise it on load (instance norm + leaky ReLU), or None; bias (N,) fp32. Returns
    (B, V, N) and, with `stats`, its sums (B, 2, N) (else an empty tensor); `pdl`: launched as a programmatic
    dependent launch (the module's note), as every launcher's `pdl`."""
    n_vertices, size = table.shape
    n_out = weight.shape[1]
    batch, c1, c2 = src1.shape[0], src1.shape[2], 0 if src2 is None else src2.shape[2]
    out, sums, sums_args = _output(table, batch, n_out, out_dtype, stats, bias)
    second = src1 if src2 is None else src2
    args = (out, *sums_args, table, weight, bias, bias if affine is None else affine, n_vertices, n_out,
            src1, table if map1 is None else map1, src1.shape[1], c1,
            second, table if map2 is None else map2, second.shape[1], c2,
            bias if norm1 is None else norm1, bias if norm2 is None else norm2)
    # K chunks as wide as the narrower segment allows (tl.dot needs 16): few-channel convs waste little.
    block_k = min(64, max(16, triton.next_power_of_2(min(c1, c2) if c2 else c1)))
    constants = dict(L=size, SLOTS=triton.next_power_of_2(size), MAPPED1=map1 is not None,
                     MAPPED2=map2 is not None, TWO=src2 is not None, AFFINE=affine is not None,
                     NORM1=norm1 is not None, NORM2=norm2 is not None, STATS=stats,
                     PRECISE=weight.dtype == torch.float32, BLOCK_K=block_k, EPS=NORM_EPS, SLOPE=LEAKY_SLOPE)
    _launch(_conv_kernel, _tuned_conv, args, constants, n_vertices, n_out, batch, pdl)
    return out, sums


def _output(table: torch.Tensor, batch: int, n_out: int, out_dtype: torch.dtype, stats: bool,
            bias: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, tuple]:
    """A convolution's output (B, V, N), its sums (B, 2, N) zeroed for the epilogue's atomics (empty without a
    norm) and its kernel's three sums arguments (any pointer when no norm)."""
    out = torch.empty(batch, table.shape[0], n_out, device=table.device, dtype=out_dtype)
    if not stats:
        return out, torch.empty(0, device=table.device, dtype=torch.float32), (bias, 0, 0)
    sums = torch.zeros(batch, 2, n_out, device=table.device, dtype=torch.float32)
    return out, sums, (sums, 2 * n_out, n_out)


def _pdl(pdl: bool) -> dict:
    """A kernel's PDL constant and, with it, the launch option that makes its launch a dependent one (where it
    can run is FusedNetwork's check, at construction)."""
    return {"PDL": True, "launch_pdl": True} if pdl else {"PDL": False}


def _launch(kernel, tuned, args: tuple, constants: dict, n_vertices: int, n_out: int, batch: int,
            pdl: bool) -> None:
    """A convolution kernel over (row tiles, column tiles, frames): the tuned tiles, or small fixed ones in
    Triton's interpreter; `pdl`: as a programmatic dependent launch."""
    if INTERPRETED:
        grid = (triton.cdiv(n_vertices, _FIXED["BLOCK_M"]), triton.cdiv(n_out, _FIXED["BLOCK_N"]), batch)
        wrap_triton(kernel)[grid](*args, **constants, **_FIXED, **_pdl(pdl))
    else:
        grid = lambda meta: (triton.cdiv(n_vertices, meta["BLOCK_M"]),  # noqa: E731
                             triton.cdiv(n_out, meta["BLOCK_N"]), batch)
        wrap_triton(tuned)[grid](*args, **constants, **_pdl(pdl))


# Narrow column blocks give coarse levels (a few hundred rows) enough programs to fill the SMs.
_GATHER_SUM_CONFIGS = [triton.Config({"BLOCK_M": m, "BLOCK_N": n}, num_warps=w)
                       for m, n, w in ((128, 16, 4), (256, 16, 4), (64, 32, 4), (128, 32, 4), (16, 64, 2),
                                       (32, 64, 4), (16, 128, 4), (32, 128, 4), (32, 256, 4), (64, 256, 8))]


def _gather_sum_configs(configs, named_args, **_):
    """Column blocks as wide as the output (a power of two, 16 to 256) or, for a wide one, 64 and up: a narrow
    output (an output layer's 3 channels) takes tall thin tiles instead of masking most of a wide one."""
    widest = min(256, max(16, triton.next_power_of_2(named_args["n_out"])))
    return [config for config in configs if min(widest, 64) <= config.kwargs["BLOCK_N"] <= widest]


_tuned_gather_sum = triton.autotune(_GATHER_SUM_CONFIGS, key=["n_vertices", "n_out", "src1_vertices", "src2_vertices"],
                                    prune_configs_by={"early_config_prune": _gather_sum_configs},
                                    restore_value=["sums_ptr"])(_gather_sum_kernel)


@triton_op(f"{NAMESPACE}::gather_sum", mutates_args=())
def gather_sum(table: torch.Tensor, src1: torch.Tensor, map1: torch.Tensor | None, src2: torch.Tensor | None,
               map2: torch.Tensor | None, bias: torch.Tensor, out_dtype: torch.dtype,
               stats: bool, pdl: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """A convolution's second half when its products came first: out[b, v] = bias + sum over the segments and
    the table's slots k of products[b, map(table[v, k]), k] (each segment's products (B, V_src, L, N) contiguous,
    its input already multiplied by its slot weights; map (V_src_table, 1) int32 or None). Returns (B, V, N) and
    its sums as `fused_conv`'s."""
    n_vertices, size = table.shape
    batch, n_out = src1.shape[0], src1.shape[3]
    out, sums, sums_args = _output(table, batch, n_out, out_dtype, stats, bias)
    second = src1 if src2 is None else src2
    args = (out, *sums_args, table, bias, n_vertices, n_out, src1, table if map1 is None else map1, src1.shape[1],
            second, table if map2 is None else map2, second.shape[1])
    constants = dict(L=size, MAPPED1=map1 is not None, MAPPED2=map2 is not None, TWO=src2 is not None,
                     STATS=stats)
    _launch(_gather_sum_kernel, _tuned_gather_sum, args, constants, n_vertices, n_out, batch, pdl)
    return out, sums


@triton_op(f"{NAMESPACE}::few_channel_conv", mutates_args=())
def few_channel_conv(table: torch.Tensor, source: torch.Tensor, rows: torch.Tensor | None,
                     affine: torch.Tensor | None, norm: torch.Tensor | None, weight: torch.Tensor,
                     bias: torch.Tensor, out_dtype: torch.dtype, stats: bool,
                     pdl: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """`fused_conv` of one segment of few channels (a handful: the loops unroll over slots x channels) in fp32
    FMAs - the network's first convolution on raw features, an output layer's last - where tensor-core tiles
    would pad K to 16 and multiply mostly zeros."""
    n_vertices, size = table.shape
    batch, src_vertices, channels = source.shape
    n_out = weight.shape[1]
    out, sums, sums_args = _output(table, batch, n_out, out_dtype, stats, bias)
    block_m, block_n = (16, 16) if INTERPRETED else (32, min(64, max(16, triton.next_power_of_2(n_out))))
    grid = (triton.cdiv(n_vertices, block_m), triton.cdiv(n_out, block_n), batch)
    wrap_triton(_few_channel_kernel)[grid](
        out, *sums_args, table, weight, bias, bias if affine is None else affine, bias if norm is None else norm,
        n_vertices, n_out, source, table if rows is None else rows, src_vertices, C=channels, L=size,
        SLOTS=max(16, triton.next_power_of_2(size)), MAPPED=rows is not None, AFFINE=affine is not None,
        NORM=norm is not None, STATS=stats, EPS=NORM_EPS, SLOPE=LEAKY_SLOPE, BLOCK_M=block_m, BLOCK_N=block_n,
        num_warps=4, **_pdl(pdl))
    return out, sums


@triton_op(f"{NAMESPACE}::normed_products", mutates_args=())
def normed_products(source: torch.Tensor, sums: torch.Tensor, weights: torch.Tensor,
                    pdl: bool = False) -> torch.Tensor:
    """leaky(instance norm of source) @ weights: source (B, V, C) contiguous, its conv's sums (B, 2, C), weights
    (C, M) (a segment's `slot_weights`). Returns (B, V, M) in the weights' dtype, as torch.matmul would."""
    batch, n_rows, channels = source.shape
    n_cols = weights.shape[1]
    out = torch.empty(batch, n_rows, n_cols, device=source.device, dtype=weights.dtype)
    args = (out, source, sums, weights, n_rows, channels, n_cols)
    constants = dict(PRECISE=weights.dtype == torch.float32, EPS=NORM_EPS, SLOPE=LEAKY_SLOPE,
                     BLOCK_K=min(64, max(16, triton.next_power_of_2(channels))))
    _launch(_normed_products_kernel, _tuned_products, args, constants, n_rows, n_cols, batch, pdl)
    return out


@triton_op(f"{NAMESPACE}::prepare", mutates_args=())
def prepare(source: torch.Tensor, rows: torch.Tensor | None, sums: torch.Tensor | None, out_dtype: torch.dtype,
            pool_max: bool, pdl: bool = False) -> torch.Tensor:
    """source (B, V_src, C) -> (B, V, C): normalised (instance norm from the source's `sums` (B, 2, C) +
    leaky ReLU) if sums is given, then reduced over each row of `rows` (V, P) int32 (mean, or max if pool_max),
    or row by row if None."""
    batch, src_vertices, channels = source.shape
    n_rows = src_vertices if rows is None else rows.shape[0]
    out = torch.empty(batch, n_rows, channels, device=source.device, dtype=out_dtype)
    block_c = min(triton.next_power_of_2(channels), 128)
    block_m = 16 if INTERPRETED else max(16, 4096 // block_c)
    grid = (triton.cdiv(n_rows, block_m), triton.cdiv(channels, block_c), batch)
    sums_args = (sums, 2 * channels) if sums is not None else (source, 0)
    wrap_triton(_prepare_kernel)[grid](
        out, source, source if rows is None else rows, *sums_args, n_rows, src_vertices, channels,
        P=1 if rows is None else rows.shape[1], MAPPED=rows is not None, NORMALIZE=sums is not None,
        POOL_MAX=pool_max, EPS=NORM_EPS, SLOPE=LEAKY_SLOPE, BLOCK_M=block_m, BLOCK_C=block_c, num_warps=4,
        **_pdl(pdl))
    return out
