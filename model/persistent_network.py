"""The fused network's whole plan in one launch: a persistent Triton kernel with a grid-wide barrier between phases.

A small network's frame (RC9 x/4 at 15k vertices) is ~45 dependent kernels of a few microseconds each, every one
at a kernel's floor (launch ramp, one partial wave, drain) plus ~1 us a graph node between them
(docs/performance.md, "Inference"). Here the plan's launches (model.fused_network: one step a convolution, a
pooling or a norm; every convolution gathering) become the steps of one kernel, grouped into phases
(`fused_network.plan_phases`: a step in the phase after its sources', so a skip connection's normalised copy runs
beside the pooling of the same value): one program per multiprocessor, each phase's output tiles dealt
round-robin over the programs, then a grid barrier (an arrival counter in global memory: release on arrival,
acquire after the spin) so the next phase reads complete inputs and complete norm sums. The steps run the same
tile functions as the separate kernels (model.triton_conv: `_conv_tile`, `_few_channel_tile`, `_prepare_tile`),
so the arithmetic is theirs.

The unfolded plan is the faster one here: a norm written once by its own step costs a barrier and a ~1 us pass,
where folded into the readers (`fold_norms`) it makes every gathering loop of the decoder 1.5-3x slower an iteration
(timestamps on an H200: docs/history/performance-log.md, "The persistent kernel's phases").

The kernel's text is generated from the plan (its shapes and flags are compile-time constants, as the separate
kernels' are) and compiled by Triton like any other; only integers and names of this module's making go into it,
never text from a file or setting. One frame's norm sums and the barrier's counter share one zeroed workspace, a
memset before the kernel; each step's sums start on their own 128-byte line.

A barrier needs every program resident at once: the grid is the GPU's multiprocessor count, one small program
each, which holds on a GPU this process has to itself (a kernel of another stream occupying SMs delays the
barrier until it ends; one that itself waited on this kernel would deadlock, which nothing here launches). More
programs than can be resident deadlock: four a multiprocessor hung on an H200, so the grid stays at one. In
Triton's interpreter (TRITON_INTERPRET=1, the CPU tests) the grid is one program, for which each barrier passes at
once.
"""
from __future__ import annotations

import dataclasses
import itertools
import linecache
from typing import NamedTuple

import torch
import triton
import triton.language as tl

from model import triton_conv
from model.layers import LEAKY_SLOPE, NORM_EPS
from model.fused_network import NETWORK_INPUT, FusedConv, Prepare, plan_phases

SUMS_ALIGN = 32                # floats: a step's norm sums start on a 128-byte line of their own
NUM_WARPS = 4


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


class _Input(NamedTuple):
    """A convolution segment as the generated call passes it (text for pointers, numbers and flags)."""

    src: str              # the frame's source pointer
    rows_map: str         # its unpooling map's argument (the table when unmapped: never read)
    rows: int             # the source's rows
    channels: int
    mapped: bool
    norm: str             # the source's norm sums pointer
    normalize: bool


@dataclasses.dataclass(frozen=True)
class _Step:
    """One step's generated call: the tiles it deals and the tile function's arguments (text)."""

    rows: int
    cols: int
    block_m: int
    block_n: int
    call: str


def _block_rows(rows: int, programs: int) -> int:
    """Rows per tile: about one tile a program (one wave), a power of two from 16 to 128."""
    return min(128, max(16, triton.next_power_of_2(-(-rows // programs))))


class PersistentPlan:
    """A FusedNetwork's plan (no products-first convolution) as one generated kernel for a grid of `programs`;
    `run(network, x, outputs)` executes it with the network's buffers."""

    def __init__(self, network, programs: int):
        self.programs = programs
        plan = network.plan
        self.vertices = [0] * len(plan)                 # a step's output rows
        self.channels = [0] * len(plan)
        self.sums_offset: dict[int, int] = {}
        offset = 0
        for index, launch in enumerate(plan):
            if isinstance(launch, FusedConv):
                self.vertices[index] = network.get_buffer(f"table_{launch.level}").shape[0]
                self.channels[index] = launch.weight.shape[1]
                if launch.stats:
                    self.sums_offset[index] = offset
                    offset += -(-2 * self.channels[index] // SUMS_ALIGN) * SUMS_ALIGN
            else:
                self.vertices[index] = self.vertices[launch.source] if launch.rows is None else launch.rows.shape[0]
                self.channels[index] = launch.channels
        self.sums_stride = max(offset, SUMS_ALIGN)
        self.names: list[str] = ["x", "affine", "sums", "sync"]   # the kernel's tensor arguments, in order
        self._tensors: list[str] = []                             # the network's buffers behind names[4:]
        steps = [self._step(index, launch, network) for index, launch in enumerate(plan)]
        phases = [[steps[index] for index in phase] for phase in plan_phases(plan)]
        self.kernel = _compile(_kernel_source(self.names, len(plan), phases))

    def _arg(self, buffer: str) -> str:
        """The kernel argument holding the network's buffer `buffer` (each passed once)."""
        if buffer not in self._tensors:
            self._tensors.append(buffer)
            self.names.append(f"a{len(self._tensors) - 1}")
        return self.names[4 + self._tensors.index(buffer)]

    def _source(self, source: int, channels: int, network) -> tuple[str, int, int]:
        """(argument, rows, channels) of a step's input: the raw features (of `channels`) or a step's output."""
        if source == NETWORK_INPUT:
            return "x", network.get_buffer("table_0").shape[0], channels
        return f"out{source}", self.vertices[source], self.channels[source]

    def _sums(self, index: int) -> str:
        return f"sums + frame * {self.sums_stride} + {self.sums_offset.get(index, 0)}"

    def _step(self, index: int, launch, network) -> _Step:
        rows, cols = self.vertices[index], self.channels[index]
        out = f"out{index} + frame * {rows * cols}"
        if isinstance(launch, Prepare):
            src, src_rows, channels = self._source(launch.source, launch.channels, network)
            block_m = _block_rows(rows, self.programs)
            block_c = min(128, triton.next_power_of_2(channels))
            mapped = launch.rows is not None
            call = (f"_prepare_tile(rows, cols, row_ok, col_ok, {out}, {src} + frame * {src_rows * channels}, "
                    f"{self._arg(f'rows_{index}_0') if mapped else 'x'}, {self._sums(launch.source)}, {src_rows}, "
                    f"{channels}, {launch.rows.shape[1] if mapped else 1}, {mapped}, {launch.normalize}, "
                    f"{network.pool_max}, {block_m}, {block_c}, {NORM_EPS!r}, {LEAKY_SLOPE!r})")
            return _Step(rows, cols, block_m, block_c, call)
        table, weight, bias = (self._arg(f"table_{launch.level}"), self._arg(f"weight_{index}"),
                               self._arg(f"bias_{index}"))
        size = network.get_buffer(f"table_{launch.level}").shape[1]
        inputs = []
        for number, segment in enumerate(launch.segments):
            src, src_rows, channels = self._source(segment.source, segment.channels, network)
            mapped = segment.rows is not None
            inputs.append(_Input(f"{src} + frame * {src_rows * channels}",
                                 self._arg(f"rows_{index}_{number}") if mapped else table, src_rows, channels,
                                 mapped, self._sums(segment.source), segment.normalize))
        block_m, block_n = _block_rows(rows, self.programs), min(64, max(16, triton.next_power_of_2(cols)))
        head = (f"rows, cols, row_ok, col_ok, {out}, {self._sums(index)}, {cols}, {table}, {weight}, {bias}, "
                f"affine")
        first = inputs[0]
        if network.forms[index] == "few":
            call = (f"_few_channel_tile({head}, {first.norm}, {cols}, {first.src}, {first.rows_map}, {first.rows}, "
                    f"{first.channels}, {size}, {max(16, triton.next_power_of_2(size))}, {first.mapped}, "
                    f"{launch.segments[0].affine}, {first.normalize}, {launch.stats}, {block_m}, {block_n}, "
                    f"{NORM_EPS!r}, {LEAKY_SLOPE!r})")
            return _Step(rows, cols, block_m, block_n, call)
        if network.forms[index] != "gather":
            raise ValueError(f"the persistent kernel gathers every convolution; step {index} is "
                             f"'{network.forms[index]}'")
        # A one-segment convolution passes its input again as the (unread) second, with 0 channels.
        second = inputs[1] if len(inputs) == 2 else first._replace(channels=0, mapped=False, normalize=False)
        narrower = min(first.channels, second.channels) if second.channels else first.channels
        block_k = min(64, max(16, triton.next_power_of_2(narrower)))
        precise = network.get_buffer(f"weight_{index}").dtype == torch.float32
        call = (f"_conv_tile({head}, {cols}, {first.src}, {first.rows_map}, {first.rows}, {first.channels}, "
                f"{second.src}, {second.rows_map}, {second.rows}, {second.channels}, {first.norm}, {second.norm}, "
                f"{size}, {triton.next_power_of_2(size)}, {first.mapped}, {second.mapped}, {len(inputs) == 2}, "
                f"{launch.segments[0].affine}, {first.normalize}, {second.normalize}, {launch.stats}, {precise}, "
                f"{block_m}, {block_n}, {block_k}, {NORM_EPS!r}, {LEAKY_SLOPE!r})")
        return _Step(rows, cols, block_m, block_n, call)

    def run(self, network, x: torch.Tensor, outputs: list[torch.Tensor]) -> None:
        """Run the kernel on x (B, V_0, C) fp32 contiguous, writing the steps' `outputs` (allocated by the
        caller, one a step)."""
        batch = x.shape[0]
        # One memset: the frames' norm sums (fp32 zeros are zero bits) and, after them, the barrier's counter.
        workspace = torch.zeros(batch * self.sums_stride + SUMS_ALIGN, device=x.device, dtype=torch.int32)
        sums = workspace[:batch * self.sums_stride].view(torch.float32)
        sync = workspace[batch * self.sums_stride:]
        tensors = [x, network.affine, sums, sync] + [network.get_buffer(name) for name in self._tensors]
        self.kernel[(self.programs,)](batch, *tensors, *outputs, PROGRAMS=self.programs, num_warps=NUM_WARPS)


def _kernel_source(names: list[str], n_steps: int, phases: list[list[_Step]]) -> str:
    """The kernel's text: each phase's tiles (its steps' one after another) dealt round-robin over the programs,
    a grid barrier after each phase but the last."""
    outs = [f"out{index}" for index in range(n_steps)]
    lines = ["@triton.jit",
             f"def persistent_network(batch, {', '.join(names + outs)}, PROGRAMS: tl.constexpr):",
             "    program = tl.program_id(0)"]
    for number, phase in enumerate(phases):
        ends, end = [], "0"                  # each step's tiles end at this tile number of the phase
        for step in phase:
            end = f"{end} + batch * {-(-step.rows // step.block_m) * -(-step.cols // step.block_n)}"
            ends.append(end)
        # Every program runs the same trip count and skips the tiles past the end.
        lines += [f"    for first in range(0, {end}, PROGRAMS):",
                  "        tile = first + program"]
        start = "0"
        for step, end in zip(phase, ends):
            lines += [f"        if (tile >= {start}) & (tile < {end}):",
                      f"            frame, rows, cols, row_ok, col_ok = _tile_of(tile - ({start}), {step.rows}, "
                      f"{step.cols}, {step.block_m}, {step.block_n})",
                      f"            {step.call}"]
            start = end
        if number < len(phases) - 1:
            lines.append(f"    _grid_barrier(sync, {number + 1} * PROGRAMS)")
    return "\n".join(lines) + "\n"


_COUNTER = itertools.count()
_COMPILED: dict[str, object] = {}


def _compile(source: str):
    """The generated kernel as a Triton JIT function (one per distinct text). Triton reads a kernel's source
    through `inspect`, so the text is registered with linecache under a file name of its own first."""
    if source in _COMPILED:
        return _COMPILED[source]
    filename = f"<persistent_network_{next(_COUNTER)}>"
    header = "import triton\nimport triton.language as tl\n"
    text = header + source
    linecache.cache[filename] = (len(text), None, text.splitlines(keepends=True), filename)
    scope = {"_conv_tile": triton_conv._conv_tile, "_few_channel_tile": triton_conv._few_channel_tile,
             "_prepare_tile": triton_conv._prepare_tile, "_tile_of": tile_of,
             "_grid_barrier": grid_barrier}
    exec(compile(text, filename, "exec"), scope)    # noqa: S102 - text of this module's making (see the module)
    _COMPILED[source] = scope["persistent_network"]
    return _COMPILED[source]


def programs_for(device: torch.device) -> int:
    """The grid: one program per multiprocessor on CUDA (all resident at once), one in the interpreter."""
    if triton_conv.INTERPRETED or device.type != "cuda":
        return 1
    return torch.cuda.get_device_properties(device).multi_processor_count
