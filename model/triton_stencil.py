"""A padded stencil's product (model.inference.padded_stencil) in one Triton kernel: Loop subdivision before the
fused network, and after it the subdivision plus the network's displacement, in the mesh's order.

On an H200 the same product as `torch.nn.functional.embedding_bag` (model.inference.stencil_product's ATen form)
took 18 us at 15k rows, and the sum and reorder after the network (an add, then an index_select run as a
scatter/gather kernel) 7 us: a sixth of a 0.15 ms frame of RC9 x/4 (docs/performance.md, I15). One program
handles BLOCK output rows of one frame, a row's few stencil entries unrolled (W is the widest row).

The launcher is a custom operator (`torch.library.triton_op`, learned_cloth::stencil) like model.triton_conv's:
torch.export keeps it as one operator, defined in an export by a copy of this module. Set TRITON_INTERPRET=1
before importing to run it on the CPU with Triton's interpreter (the tests do).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch.library import triton_op, wrap_triton

from model.triton_conv import NAMESPACE

BLOCK = 32          # rows a program: 4 x more programs than 128 rows, 1.7 us where 3.0 (15k rows, H200)


@triton.jit
def _stencil_kernel(out_ptr, x_ptr, columns_ptr, weights_ptr, rows_ptr, add_ptr, n_out, n_in, n_stencil,
                    W: tl.constexpr, C: tl.constexpr, C_PAD: tl.constexpr, ROWS: tl.constexpr,
                    ADD: tl.constexpr, BLOCK_ROWS: tl.constexpr):
    frame = tl.program_id(1).to(tl.int64)
    out_row = tl.program_id(0) * BLOCK_ROWS + tl.arange(0, BLOCK_ROWS)
    ok = out_row < n_out
    if ROWS:
        row = tl.load(rows_ptr + out_row, mask=ok, other=0).to(tl.int64)
    else:
        row = out_row.to(tl.int64)
    channel = tl.arange(0, C_PAD)
    both = ok[:, None] & (channel < C)[None, :]
    x_frame = x_ptr + frame * n_in * C
    total = tl.zeros((BLOCK_ROWS, C_PAD), dtype=tl.float32)
    for k in tl.static_range(W):        # the entries in column order, as the ATen form sums them
        column = tl.load(columns_ptr + row * W + k, mask=ok, other=0)
        weight = tl.load(weights_ptr + row * W + k, mask=ok, other=0.0)
        value = tl.load(x_frame + column[:, None] * C + channel[None, :], mask=both, other=0.0)
        total += weight[:, None] * value.to(tl.float32)
    if ADD:
        total += tl.load(add_ptr + frame * n_stencil * C + row[:, None] * C + channel[None, :], mask=both,
                         other=0.0).to(tl.float32)
    tl.store(out_ptr + frame * n_out * C + out_row[:, None] * C + channel[None, :], total, mask=both)


@triton_op(f"{NAMESPACE}::stencil", mutates_args=())
def stencil(columns: torch.Tensor, weights: torch.Tensor, x: torch.Tensor, rows: torch.Tensor | None,
            add: torch.Tensor | None) -> torch.Tensor:
    """out[b, i] = sum_k weights[r, k] x[b, columns[r, k]] (+ add[b, r]) with r = rows[i] (or i without rows):
    (B, len(rows) or R, C) in x's dtype, summed in fp32. columns (R, W) int64, weights (R, W) fp32, x (B, V, C)
    and add (B, R, C) contiguous."""
    batch, n_in, channels = x.shape
    n_out = len(columns) if rows is None else len(rows)
    out = x.new_empty(batch, n_out, channels)
    if batch == 0 or n_out == 0:
        return out
    grid = (triton.cdiv(n_out, BLOCK), batch)
    wrap_triton(_stencil_kernel)[grid](
        out, x, columns, weights, columns if rows is None else rows, x if add is None else add, n_out, n_in,
        len(columns), W=columns.shape[1], C=channels, C_PAD=triton.next_power_of_2(channels),
        ROWS=rows is not None, ADD=add is not None, BLOCK_ROWS=BLOCK, num_warps=4)
    return out
