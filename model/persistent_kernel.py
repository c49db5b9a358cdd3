"""The persistent kernel of a fused network's plan, generated from a spec and launched as one operator
(`learned_cloth::persistent`): the kernel side of model.persistent_network, which writes the spec.

The spec is data, not code: a JSON object of the plan's steps (each a kind, shapes, flags, which earlier step or
buffer it reads) and its phases. Here it is checked (model.persistent_spec's `checked_spec`: only integers,
booleans and the known keys and kinds) and turned into the kernel's text with the names and numbers it holds, so
a spec from an exported program cannot put anything else into the text. The text depends on the GPU as well (the
grid is its multiprocessor count and the tiles' rows follow from it), so it is made where the kernel runs, once
per spec and grid: an export carries the spec and this module, and the kernel fits whatever GPU loads it.

The kernel: one program per multiprocessor, each phase's output tiles dealt round-robin over the programs, then a
grid barrier (an arrival counter in global memory: release on arrival, acquire after the spin) so the next phase
reads complete inputs and complete norm sums. The steps run model.triton_conv's tile functions (`_conv_tile`,
`_few_channel_tile`, `_prepare_tile`), so the arithmetic is the separate kernels'. One frame's norm sums and the
barrier's counter share one zeroed workspace; each step's sums start on their own 128-byte line.

A barrier needs every program resident at once: the grid is the GPU's multiprocessor count, one small program
each, which holds on a GPU this process has to itself (a kernel of another stream occupying SMs delays the
barrier until it ends). More programs than can be resident deadlock: four a multiprocessor hung on an H200, so the
grid stays at one. In Triton's interpreter (TRITON_INTERPRET=1, the CPU tests) the grid is one program, for which
each barrier passes at once.
"""
from __future__ import annotations

import functools
import itertools
import linecache

import torch
import triton
import triton.language as tl
from torch.library import triton_op, wrap_triton

from model.layers import LEAKY_SLOPE, NORM_EPS
from model.persistent_spec import NETWORK_INPUT, SUMS_ALIGN, checked_spec
from model.triton_conv import INTERPRETED, NAMESPACE, _conv_tile, _few_channel_tile, _prepare_tile

NUM_WARPS = 4
HIDDEN_DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16}     # persistent_spec.HIDDEN_DTYPE_NAMES


@triton.jit
def tile_of(tile, n_rows, n_cols, BLOCK_M: tl.constexpr, BLOCK_N: tl.constexpr):
    """Tile number `tile` of a step over (frames, row tiles, column tiles): its frame, rows, columns and which
    of them exist (as model.triton_conv's `_tile` gives a separate kernel's program)."""
    col_tiles = tl.cdiv(n_cols, BLOCK_N)
    per_frame = tl.cdiv(n_rows, BLOCK_M) * col_tiles
    frame = tile // per_frame
    rest = tile - frame * per_frame
    rows = (rest // col_tiles) * BLOCK_M + tl.arange(0, BLOCK_M)
    cols = (rest % col_tiles) * BLOCK_N + tl.arange(0, BLOCK_N)
    return frame.to(tl.int64), rows, cols, rows < n_rows, cols < n_cols


@triton.jit
def grid_barrier(counter, target):
    """Wait until `target` arrivals (this program's included): every thread's writes so far are published
    (a CTA barrier, then a release add at GPU scope), and after the spin an acquire makes the other programs'
    writes visible to this one's loads."""
    tl.debug_barrier()
    tl.atomic_add(counter, 1, sem="release", scope="gpu")
    while tl.load(counter, volatile=True) < target:
        pass
    tl.atomic_add(counter, 0, sem="acquire", scope="gpu")
    tl.debug_barrier()


def block_rows(rows: int, programs: int) -> int:
    """Rows per tile: about one tile a program (one wave), a power of two from 16 to 128."""
    return min(128, max(16, triton.next_power_of_2(-(-rows // programs))))


def _source(source: int, rows: int, channels: int) -> str:
    name = "x" if source == NETWORK_INPUT else f"out{source}"
    return f"{name} + frame * {rows * channels}"


def _sums(spec: dict, offset: int) -> str:
    return f"sums + frame * {spec['sums_stride']} + {offset}"


def _call(spec: dict, index: int, programs: int) -> tuple[int, int, str]:
    """A step's tile sizes and the call of its tile function (text of this module's making from checked numbers)."""
    step = spec["steps"][index]
    rows, cols = step["rows"], step["cols"]
    out = f"out{index} + frame * {rows * cols}"
    block_m = block_rows(rows, programs)
    if step["kind"] == "prepare":
        block_c = min(128, triton.next_power_of_2(step["src_channels"]))
        mapped = step["map"] >= 0
        rows_map = f"a{step['map']}" if mapped else "x"
        call = (f"_prepare_tile(rows, cols, row_ok, col_ok, {out}, "
                f"{_source(step['source'], step['src_rows'], step['src_channels'])}, {rows_map}, "
                f"{_sums(spec, step['sums'])}, "
                f"{step['src_rows']}, {step['src_channels']}, {step['map_width'] if mapped else 1}, {mapped}, "
                f"{step['normalize']}, {step['pool_max']}, {block_m}, {block_c}, {NORM_EPS!r}, {LEAKY_SLOPE!r})")
        return block_m, block_c, call
    table, size = f"a{step['table']}", step["table_width"]
    inputs = [(_source(s["source"], s["src_rows"], s["channels"]), f"a{s['map']}" if s["map"] >= 0 else table,
               s["src_rows"], s["channels"], s["map"] >= 0, _sums(spec, s["sums"]), s["normalize"])
              for s in step["inputs"]]
    block_n = min(64, max(16, triton.next_power_of_2(cols)))
    head = (f"rows, cols, row_ok, col_ok, {out}, {_sums(spec, step['sums'])}, {cols}, {table}, a{step['weight']}, "
            f"a{step['bias']}, affine")
    src, rows_map, src_rows, channels, mapped, norm, normalize = inputs[0]
    if step["kind"] == "few":
        call = (f"_few_channel_tile({head}, {norm}, {cols}, {src}, {rows_map}, {src_rows}, {channels}, {size}, "
                f"{max(16, triton.next_power_of_2(size))}, {mapped}, {step['affine']}, {normalize}, "
                f"{step['stats']}, {block_m}, {block_n}, {NORM_EPS!r}, {LEAKY_SLOPE!r})")
        return block_m, block_n, call
    # A one-segment convolution passes its input again as the (unread) second, with 0 channels.
    second = inputs[1] if len(inputs) == 2 else (src, rows_map, src_rows, 0, False, norm, False)
    narrower = min(channels, second[3]) if second[3] else channels
    block_k = min(64, max(16, triton.next_power_of_2(narrower)))
    call = (f"_conv_tile({head}, {cols}, {src}, {rows_map}, {src_rows}, {channels}, {second[0]}, {second[1]}, "
            f"{second[2]}, {second[3]}, {norm}, {second[5]}, {size}, {triton.next_power_of_2(size)}, {mapped}, "
            f"{second[4]}, {len(inputs) == 2}, {step['affine']}, {normalize}, {second[6]}, {step['stats']}, "
            f"{step['precise']}, {block_m}, {block_n}, {block_k}, {NORM_EPS!r}, {LEAKY_SLOPE!r})")
    return block_m, block_n, call


def kernel_source(spec: dict, n_buffers: int, programs: int) -> str:
    """The kernel's text for a checked spec: each phase's tiles (its steps' one after another) dealt round-robin
    over the programs, a grid barrier after each phase but the last."""
    steps = spec["steps"]
    names = ["x", "affine", "sums", "sync", *(f"a{i}" for i in range(n_buffers)),
             *(f"out{i}" for i in range(len(steps)))]
    lines = ["@triton.jit",
             f"def persistent_network(batch, {', '.join(names)}, PROGRAMS: tl.constexpr):",
             "    program = tl.program_id(0)"]
    for number, phase in enumerate(spec["phases"]):
        calls = [(steps[index], *_call(spec, index, programs)) for index in phase]
        ends, end = [], "0"                  # each step's tiles end at this tile number of the phase
        for step, block_m, block_n, _ in calls:
            end = f"{end} + batch * {-(-step['rows'] // block_m) * -(-step['cols'] // block_n)}"
            ends.append(end)
        # Every program runs the same trip count and skips the tiles past the end.
        lines += [f"    for first in range(0, {end}, PROGRAMS):", "        tile = first + program"]
        start = "0"
        for (step, block_m, block_n, call), end in zip(calls, ends):
            lines += [f"        if (tile >= {start}) & (tile < {end}):",
                      f"            frame, rows, cols, row_ok, col_ok = _tile_of(tile - ({start}), {step['rows']}, "
                      f"{step['cols']}, {block_m}, {block_n})",
                      f"            {call}"]
            start = end
        if number < len(spec["phases"]) - 1:
            lines.append(f"    _grid_barrier(sync, {number + 1} * PROGRAMS)")
    return "\n".join(lines) + "\n"


_COUNTER = itertools.count()


@functools.lru_cache(maxsize=None)
def _kernel(spec: str, n_buffers: int, programs: int) -> tuple[dict, object]:
    """The checked spec and its kernel for a grid of `programs`, made once per (spec, buffers, grid): a call
    pays neither the check nor the text again. Triton reads a kernel's source through `inspect`, so the text is
    registered with linecache under a file name of its own first."""
    checked = checked_spec(spec, n_buffers)
    filename = f"<persistent_network_{next(_COUNTER)}>"
    text = "import triton\nimport triton.language as tl\n" + kernel_source(checked, n_buffers, programs)
    linecache.cache[filename] = (len(text), None, text.splitlines(keepends=True), filename)
    scope = {"_conv_tile": _conv_tile, "_few_channel_tile": _few_channel_tile, "_prepare_tile": _prepare_tile,
             "_tile_of": tile_of, "_grid_barrier": grid_barrier}
    exec(compile(text, filename, "exec"), scope)    # noqa: S102 - text of this module's making (see the module)
    return checked, scope["persistent_network"]


def programs_for(device: torch.device) -> int:
    """The grid: one program per multiprocessor on CUDA (all resident at once), one in the interpreter."""
    if INTERPRETED or device.type != "cuda":
        return 1
    return torch.cuda.get_device_properties(device).multi_processor_count


@triton_op(f"{NAMESPACE}::persistent", mutates_args=())
def persistent(x: torch.Tensor, affine: torch.Tensor, buffers: list[torch.Tensor], spec: str) -> torch.Tensor:
    """The network of `spec` (model.persistent_network.persistent_spec) on raw features x (B, V_0, C) fp32
    contiguous, with the network's `buffers` (tables, weights, biases, maps, in the spec's numbering): its last
    step's output (B, V_0, out) fp32, the other steps' in the spec's hidden dtype."""
    programs = programs_for(x.device)
    checked, kernel = _kernel(spec, len(buffers), programs)
    batch, steps = x.shape[0], checked["steps"]
    hidden = HIDDEN_DTYPES[checked["hidden_dtype"]]
    outputs = [x.new_empty(batch, step["rows"], step["cols"],
                           dtype=torch.float32 if index == len(steps) - 1 else hidden)
               for index, step in enumerate(steps)]
    # One memset: the frames' norm sums (fp32 zeros are zero bits) and, after them, the barrier's counter.
    stride = checked["sums_stride"]
    workspace = torch.zeros(batch * stride + SUMS_ALIGN, device=x.device, dtype=torch.int32)
    sums, sync = workspace[:batch * stride].view(torch.float32), workspace[batch * stride:]
    wrap_triton(kernel)[(programs,)](batch, x, affine, sums, sync, *buffers, *outputs, PROGRAMS=programs,
                                     num_warps=NUM_WARPS)
    return outputs[-1]
