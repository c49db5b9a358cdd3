"""The encoder-decoder in few launches a frame: what `FastNetwork` computes, one or two kernels per convolution.

`FastNetwork` runs ~150 small kernels a frame (a gather, a matmul, norm statistics, pool and unpool copies,
concatenations): on an H100 the frame is bound by launches and by the gathers' memory traffic, not by the
matmuls (docs/history/performance-log.md, "Deployment path"). Here the steps between convolutions are folded into few
launches (model.triton_conv):

* **conv** -> products first where it has >= 16 input channels (`products_first`: a cuBLAS matmul by every
  slot's weights, then triton_conv.gather_sum), fp32 rank-1 updates for a few channels (`few_channels`), else one
  gather-GEMM: the table's neighbour rows are loaded straight into the matmul's tiles, never
  written out; an unpooling (or a chain of them) is a 1-wide row map the gather reads through; a concatenation is
  a second input segment filling the next weight rows; the conv's epilogue adds the bias and, when a norm reads
  the output, the per-channel sums of it and of its square (atomics into the conv's own zeroed (B, 2, N) buffer:
  each launcher is a functional custom operator, so that torch.export keeps the network whole, one operator a launch).
* **norm** -> a `Prepare` launch turns the sums into mean and 1/std and writes leaky((x - mean) / std) once, so
  the 9-13 gathers of each value do not repeat the arithmetic; a pooling (or a chain of k of them, a 2^k-wide map
  averaged or maxed) is folded into the same kind of launch. With `fold_norms` (for narrow networks, whose
  frame is bound by the number of launches rather than by arithmetic) a norm without a pooling is applied
  instead by the convolutions that read the value, on load (`Segment.normalize`): a products-first one computes
  that segment's products in a Triton matmul whose prologue normalises (triton_conv.normed_products) instead of
  cuBLAS's, a gathering one normalises what it gathers - one launch less per norm and per skip connection.
* **row widths** -> `aligned_plan` pads every stored width to a multiple of 16 channels with zeros, so rows are
  16-byte aligned and loads vectorise (an exact transformation).
* **input normalisation** -> the first convolution's prologue, (x - offset) / scale, on its few channels; the
  output scale is folded into the last convolution's weights.

With `persistent` the plan's launches become the steps of one kernel (model.persistent_network: a grid barrier
between phases of steps, `plan_phases`; every convolution gathering), which removes the launches' floors at the
cost of cuBLAS's products: faster for a narrow network (RC9 x/4), much slower for a wide one (RC13), so an option,
off by default; best without `fold_norms` (a norm on load slows every gathering loop that reads it).

The plan (`fused_plan`) is the network compiled to those launches; `run_plan_reference` executes it with PyTorch
operators on any device and is the specification the Triton kernels are tested against; `FusedNetwork` runs it
on CUDA. The variance is E[x^2] - E[x]^2 of fp32 sums (the form a one-pass epilogue can accumulate), so results
differ from the eager two-pass norm by rounding (tests/model/test_fused_network.py measures it).
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import torch
from torch import nn

from model.layers import LEAKY_SLOPE, NORM_EPS, mesh_conv
from model.mesh_hierarchy import MeshHierarchy
from model.networks import EncoderDecoder

NETWORK_INPUT = -1          # a source id: the raw features, not a launch's output


@dataclasses.dataclass(frozen=True)
class Segment:
    """A run of a convolution's input channels: `channels` of `source` (NETWORK_INPUT or a launch's index) at
    each table vertex's row `rows[v]` (None: the vertex itself); `affine`: (x - offset) / scale on load;
    `normalize`: instance norm (from the source convolution's sums) + leaky ReLU on load."""

    source: int
    channels: int
    rows: np.ndarray | None = None
    affine: bool = False
    normalize: bool = False


@dataclasses.dataclass(frozen=True)
class FusedConv:
    """out = gather(segments at level's table) @ weight + bias; `stats`: also sum the output for a norm."""

    level: int
    segments: tuple[Segment, ...]
    weight: torch.Tensor        # (L * sum(channels), out), slot-major as model.layers.mesh_conv, fp64
    bias: torch.Tensor          # (out,), fp64
    stats: bool = False


@dataclasses.dataclass(frozen=True)
class Prepare:
    """out[v] = reduce over p of f(source[rows[v, p]]), f = instance norm + leaky ReLU (from the source's sums)
    if `normalize` else identity, reduce = the network's pooling; rows None: out = f(source)."""

    source: int
    channels: int
    rows: np.ndarray | None
    normalize: bool


@dataclasses.dataclass
class _Value:
    """What the step list holds between launches: rows of a stored tensor, seen through a map, maybe normed."""

    source: int
    channels: int
    rows: np.ndarray | None = None
    normed: bool = False


def _compose(rows: np.ndarray | None, index: np.ndarray) -> np.ndarray:
    """The map of `index` (V_new,) or (V_new, K) applied after `rows` (V_old, P) -> (V_new, K * P)."""
    index = index.reshape(len(index), -1)
    if rows is None:
        return index
    return np.concatenate([rows[index[:, k]] for k in range(index.shape[1])], axis=1)


class _Planner:
    """Turns step-list values into launches, normalising each conv output once whoever reads it (or, with
    `fold_norms`, wherever it is read)."""

    def __init__(self, fold_norms: bool):
        self.plan: list[FusedConv | Prepare] = []
        self.normalised: dict[int, int] = {}
        self.fold_norms = fold_norms

    def emit(self, launch: FusedConv | Prepare) -> int:
        self.plan.append(launch)
        return len(self.plan) - 1

    def segment(self, value: _Value) -> Segment:
        source, rows = value.source, value.rows
        if rows is not None and rows.shape[1] > 1:      # a pooling: reduce once, at the coarse level
            source, rows = self.emit(Prepare(source, value.channels, rows, normalize=value.normed)), None
        elif value.normed and self.fold_norms:
            return Segment(source, value.channels, rows, normalize=True)
        elif value.normed:
            if source not in self.normalised:
                self.normalised[source] = self.emit(Prepare(source, value.channels, None, normalize=True))
            source = self.normalised[source]
        return Segment(source, value.channels, rows, affine=source == NETWORK_INPUT)


def fused_plan(net: EncoderDecoder, mesh: MeshHierarchy, output_scale: float,
               fold_norms: bool = False) -> list[FusedConv | Prepare]:
    """The encoder-decoder's steps as launches over `mesh`, the last one the output; `fold_norms`: a norm
    without a pooling applied by its readers on load. Raises ValueError for a network or step it cannot fuse."""
    if not isinstance(net, EncoderDecoder):
        raise ValueError(f"fused inference runs the encoder-decoder only, got a {type(net).__name__}")
    net.check_mesh(mesh)
    pool = [t.cpu().numpy() for t in mesh.pool]
    unpool = [t.cpu().numpy() for t in mesh.unpool]
    planner = _Planner(fold_norms)
    value: _Value | list[_Value] = _Value(NETWORK_INPUT, net.in_channels)
    skips: list[_Value] = []
    last = len(net.convs) - 1
    for step in net.steps:
        if step.op == "conv":
            conv = net.convs[step.index]
            scale = output_scale if step.index == last else 1.0
            segments = tuple(planner.segment(v) for v in (value if isinstance(value, list) else [value]))
            value = _Value(planner.emit(FusedConv(step.level, segments, conv.weight.detach().double().cpu() * scale,
                                                  conv.bias.detach().double().cpu() * scale)), conv.out_channels)
        elif step.op == "norm":
            if isinstance(value, list) or value.rows is not None or value.source == NETWORK_INPUT:
                raise ValueError("a norm must directly follow a convolution to be fused")
            planner.plan[value.source] = dataclasses.replace(planner.plan[value.source], stats=True)
            value = dataclasses.replace(value, normed=True)
        elif step.op == "save":
            skips.append(value)
        elif step.op in ("pool", "unpool"):
            index = pool[step.level] if step.op == "pool" else unpool[step.level]
            value = dataclasses.replace(value, rows=_compose(value.rows, index))
        elif step.op == "concat":
            value = [value, skips.pop()]
        else:
            raise ValueError(f"no fused form of the step '{step.op}'")
    if not isinstance(planner.plan[-1], FusedConv) or value.source != len(planner.plan) - 1:
        raise ValueError("the network must end with a convolution to be fused")
    return planner.plan


def plan_phases(plan: list[FusedConv | Prepare]) -> list[list[int]]:
    """The plan's steps grouped into phases, in order: a step runs in the phase after the latest of its sources'
    (its inputs and their norm sums): steps of one phase read only finished values, so they may run at once - in
    model.persistent_network's kernel, between the same two grid barriers (a skip connection's normalised copy
    beside the pooling that reads the same convolution)."""
    phase_of: list[int] = []
    for launch in plan:
        sources = [launch.source] if isinstance(launch, Prepare) else [s.source for s in launch.segments]
        phase_of.append(1 + max((phase_of[s] for s in sources if s != NETWORK_INPUT), default=-1))
    return [[index for index, phase in enumerate(phase_of) if phase == number]
            for number in range(max(phase_of) + 1)]


# Below this many input channels a segment's products (L * out values a row) outweigh the gathered inputs they
# replace (L * channels) by too much, and the input affine is applied on load: those convolutions gather first.
PRODUCTS_MIN_CHANNELS = 16
# Up to this many input channels (one segment) a gathering convolution is fp32 rank-1 updates, not a tl.dot
# whose K would be padded to 16.
FEW_CHANNELS = 8
# Every stored row's width a multiple of this many values (zero-padded channels): rows start 16-byte aligned in
# bf16, so Triton and cuBLAS load them in vectors, not value by value (docs/performance.md measures it).
ALIGN = 16


def products_first(launch: FusedConv) -> bool:
    """Whether the convolution runs as dense products then a gather-sum (`slot_weights`, triton_conv.gather_sum):
    each input row times every slot's weights in one large matmul (cuBLAS's rate, and an unpooled segment at its
    coarse level), then each vertex sums its table neighbours' slot products - a memory-bound pass without the
    gather-GEMM's latency-bound loads. The choice is measured in docs/performance.md."""
    return can_take_products(launch) and min(s.channels for s in launch.segments) >= PRODUCTS_MIN_CHANNELS


def can_take_products(launch: FusedConv) -> bool:
    """Whether the convolution's inputs may be multiplied before the gather: no input affine (whose few raw
    channels the first convolution gathers)."""
    return not any(s.affine for s in launch.segments)


def few_channels(launch: FusedConv) -> bool:
    """Whether a gathering convolution reads so few channels that fp32 rank-1 updates beat a tensor-core dot."""
    return len(launch.segments) == 1 and launch.segments[0].channels <= FEW_CHANNELS


def _round_up(n: int, align: int) -> int:
    return -(-n // align) * align


def aligned_plan(plan: list[FusedConv | Prepare], align: int, narrow: int) -> list[FusedConv | Prepare]:
    """The same network with every launch's output widened to a multiple of `align` channels - but the last (the
    answer) and those of at most `narrow` channels (padding would multiply what they store) - by zero weight
    columns and bias entries, and zero weight rows for the added input channels. A padded
    channel is 0 after every step (its norm: mean 0, variance 0, (0 - 0) / sqrt(eps) = 0), so the output is the
    plan's exactly; `run_plan_reference` runs either."""
    widths: dict[int, int] = {}         # launch index -> stored width; the network input stays raw
    width_of = lambda item: item.channels if item.source == NETWORK_INPUT else widths[item.source]  # noqa: E731
    aligned: list[FusedConv | Prepare] = []
    for index, launch in enumerate(plan):
        if isinstance(launch, Prepare):
            widths[index] = width_of(launch)
            aligned.append(dataclasses.replace(launch, channels=widths[index]))
            continue
        n_out = launch.weight.shape[1]
        n_wide = n_out if index == len(plan) - 1 or n_out <= narrow else _round_up(n_out, align)
        segments = tuple(dataclasses.replace(s, channels=width_of(s)) for s in launch.segments)
        size = launch.weight.shape[0] // sum(s.channels for s in launch.segments)
        old = launch.weight.reshape(size, -1, n_out)
        weight = torch.zeros(size, sum(s.channels for s in segments), n_wide, dtype=launch.weight.dtype)
        start, wide_start = 0, 0
        for segment, wide in zip(launch.segments, segments):
            weight[:, wide_start:wide_start + segment.channels, :n_out] = old[:, start:start + segment.channels]
            start, wide_start = start + segment.channels, wide_start + wide.channels
        bias = torch.cat([launch.bias, launch.bias.new_zeros(n_wide - n_out)])
        widths[index] = n_wide
        aligned.append(dataclasses.replace(launch, segments=segments, weight=weight.reshape(-1, n_wide), bias=bias))
    return aligned


def slot_weights(launch: FusedConv) -> list[torch.Tensor]:
    """Per segment, its rows of the slot-major weight as (channels, L * out): segment input @ it = every slot's
    product, slot k in columns k * out ... (k + 1) * out."""
    width, n_out = sum(s.channels for s in launch.segments), launch.weight.shape[1]
    by_slot = launch.weight.reshape(-1, width, n_out)
    offsets = np.cumsum([0] + [s.channels for s in launch.segments])
    return [by_slot[:, start:end].permute(1, 0, 2).reshape(end - start, -1)
            for start, end in zip(offsets[:-1], offsets[1:])]


def sums_of(x: torch.Tensor) -> torch.Tensor:
    """(B, 2, C) per-channel sums of x and x^2 over the vertices in fp32: what a conv's epilogue adds up."""
    wide = x.float()
    return torch.stack([wide.sum(dim=1), (wide * wide).sum(dim=1)], dim=1)


def norm_from_sums(sums: torch.Tensor, n_vertices: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(mean, 1/std) (B, C) of an instance norm from `sums_of`."""
    mean = sums[:, 0] / n_vertices
    var = torch.clamp(sums[:, 1] / n_vertices - mean * mean, min=0.0)
    return mean, torch.rsqrt(var + NORM_EPS)


def run_plan_reference(plan: list[FusedConv | Prepare], tables: list[torch.Tensor], x: torch.Tensor,
                       input_offset: torch.Tensor, input_scale: torch.Tensor, pool_max: bool) -> torch.Tensor:
    """Execute `plan` with PyTorch operators in fp32: x (B, V_0, C_in) raw -> (B, V_0, out). `tables[l]` is
    level l's (V_l, L) convolution table with +1 ids."""
    outputs: list[torch.Tensor] = []
    sums: dict[int, torch.Tensor] = {}
    source_of = lambda index: x.float() if index == NETWORK_INPUT else outputs[index]  # noqa: E731
    through = lambda values, rows: values if rows is None else values.index_select(  # noqa: E731
        1, torch.as_tensor(rows, device=x.device).reshape(-1)).reshape(x.shape[0], *rows.shape, -1)
    for launch in plan:
        if isinstance(launch, Prepare):
            values = source_of(launch.source)
            if launch.normalize:
                mean, inv_std = norm_from_sums(sums[launch.source], values.shape[1])
                values = nn.functional.leaky_relu((values - mean[:, None]) * inv_std[:, None], LEAKY_SLOPE)
            if launch.rows is not None:
                picked = through(values, launch.rows)
                values = picked.amax(dim=2) if pool_max else picked.mean(dim=2)
            outputs.append(values)
            continue
        parts = []
        for segment in launch.segments:
            values = source_of(segment.source)
            if segment.affine:
                values = (values - input_offset) / input_scale
            if segment.normalize:
                mean, inv_std = norm_from_sums(sums[segment.source], values.shape[1])
                values = nn.functional.leaky_relu((values - mean[:, None]) * inv_std[:, None], LEAKY_SLOPE)
            parts.append(values if segment.rows is None else through(values, segment.rows)[:, :, 0])
        out = mesh_conv(torch.cat(parts, dim=-1), tables[launch.level], launch.weight.float().to(x.device),
                        launch.bias.float().to(x.device))
        if launch.stats:
            sums[len(outputs)] = sums_of(out)
        outputs.append(out)
    return outputs[-1]


def _pdl_supported() -> bool:
    """Whether the kernels can be dependent launches here: a Hopper or later GPU (sm_90: grid dependency control)
    and a compiling Triton that has it (Triton comes with PyTorch's CUDA builds only)."""
    if not torch.cuda.is_available() or torch.cuda.get_device_capability()[0] < 9:
        return False
    try:
        from model.triton_conv import PDL_SUPPORTED
    except ImportError:
        return False
    return PDL_SUPPORTED


class FusedNetwork(nn.Module):
    """`FastNetwork`'s function (raw features (B, V_0, C) in the level-0 order of `mesh` -> scaled displacement
    (B, V_0, out) fp32) in the plan's launches, on CUDA. `dtype` is the hidden layers' storage and matmul type
    (bf16: fp32 accumulation and fp32 norm statistics); the first and last convolutions stay fp32 in full
    precision, as FastNetwork's, since raw positions and the answer itself lose too much in bf16."""

    def __init__(self, net: EncoderDecoder, mesh: MeshHierarchy, input_offset: torch.Tensor,
                 input_scale: torch.Tensor, output_scale: float, dtype: torch.dtype = torch.float32,
                 products: bool | None = None, fold_norms: bool = False, pdl: bool = False,
                 persistent: bool = False):
        """`products`: how the convolutions run - None: each by the rules (`products_first`, then
        `few_channels`, else a gather-GEMM); True: products first wherever nothing applied on load forbids it;
        False: every one a gather-GEMM (the form before products-first, for comparison). `fold_norms`: norms
        without a pooling applied on load by the convolutions reading them (fewer launches; see the module).
        `pdl`: each Triton kernel a programmatic dependent launch (model.triton_conv; Hopper, CUDA only): its
        launch overlaps the kernel before it. Off by default until measured faster; the export keeps it off.
        `persistent`: the whole plan in one launch (model.persistent_network; no convolution products first: a
        few-channel one as the rules say, the others gathering), a grid barrier between its steps."""
        super().__init__()
        if persistent and (pdl or products):
            raise ValueError("persistent: one launch, whose convolutions gather (no pdl, no products first)")
        if pdl and not _pdl_supported():
            raise ValueError("pdl: needs a CUDA build of Triton with grid dependency control (not the interpreter) "
                             "and a Hopper or later GPU")
        self.pdl, self.persistent = pdl, persistent
        self._persistent_spec = None        # the persistent kernel's spec, made at the first call (needs Triton)
        mesh = mesh.to("cpu")
        self.plan = aligned_plan(fused_plan(net, mesh, output_scale, fold_norms), ALIGN, FEW_CHANNELS)
        self.pool_max = net.pool_kind == "max"
        self.dtype = dtype
        convs = [i for i, launch in enumerate(self.plan) if isinstance(launch, FusedConv)]
        full_precision = {convs[0], convs[-1]}

        def form(launch: FusedConv) -> str:
            if products is False:
                return "gather"
            if not persistent and can_take_products(launch) and (products or products_first(launch)):
                return "products"
            return "few" if few_channels(launch) else "gather"
        self.forms = {index: form(self.plan[index]) for index in convs}
        for level, table in enumerate(mesh.conv):
            self.register_buffer(f"table_{level}", table.to(torch.int32).contiguous())
        for index, launch in enumerate(self.plan):
            if isinstance(launch, FusedConv):
                kind = torch.float32 if index in full_precision else dtype
                self.register_buffer(f"bias_{index}", launch.bias.float())
                if self.forms[index] == "products":     # the weights in the products' layout only
                    for number, weights in enumerate(slot_weights(launch)):
                        self.register_buffer(f"slot_weights_{index}_{number}", weights.to(kind).contiguous())
                else:
                    self.register_buffer(f"weight_{index}", launch.weight.to(kind).contiguous())
                rows = [segment.rows for segment in launch.segments]
            else:
                rows = [launch.rows]
            for number, map_rows in enumerate(rows):
                if map_rows is not None:
                    self.register_buffer(f"rows_{index}_{number}",
                                         torch.as_tensor(map_rows, dtype=torch.int32).contiguous())
        self.register_buffer("affine", torch.cat([input_offset.detach().float().cpu(),
                                                  1.0 / input_scale.detach().float().cpu()]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (x.is_cuda or os.environ.get("TRITON_INTERPRET") == "1"):
            raise ValueError("the fused network runs on CUDA (FastNetwork is the CPU path)")
        # Imported here: Triton comes with PyTorch's CUDA builds and is not a requirement of the CPU install. Each
        # launcher is a custom operator (torch.library.triton_op), so torch.export keeps it as one operator of the
        # program (deploy/export.py).
        from model.triton_conv import few_channel_conv, fused_conv, gather_sum, normed_products, prepare

        if self.persistent:
            return self._run_persistent(x)
        outputs: list[torch.Tensor] = []
        sums: dict[int, torch.Tensor] = {}        # a normed conv's index -> its output's sums (B, 2, N)
        source_of = lambda index: x.float().contiguous() if index == NETWORK_INPUT else outputs[index]  # noqa: E731
        for index, launch in enumerate(self.plan):
            if isinstance(launch, Prepare):
                outputs.append(prepare(source_of(launch.source), getattr(self, f"rows_{index}_0", None),
                                       sums[launch.source] if launch.normalize else None, self.dtype,
                                       self.pool_max, self.pdl))
                continue
            segments = [(source_of(segment.source), getattr(self, f"rows_{index}_{number}", None))
                        for number, segment in enumerate(launch.segments)]
            norms = [sums[segment.source] if segment.normalize else None for segment in launch.segments]
            second = segments[1] if len(segments) == 2 else (None, None)
            table, bias = getattr(self, f"table_{launch.level}"), getattr(self, f"bias_{index}")
            out_dtype = self.dtype if index < len(self.plan) - 1 else torch.float32
            if self.forms[index] == "products":
                products = []
                for number, (source, rows) in enumerate(segments):
                    weights = getattr(self, f"slot_weights_{index}_{number}")
                    if norms[number] is not None:
                        product = normed_products(source, norms[number], weights, self.pdl)
                    else:
                        product = torch.matmul(source.to(weights.dtype), weights)
                    products.append(product.view(*source.shape[:2], table.shape[1], -1))
                out, sums[index] = gather_sum(table, products[0], segments[0][1],
                                              products[1] if len(products) == 2 else None, second[1], bias,
                                              out_dtype, launch.stats, self.pdl)
            else:
                affine = self.affine if launch.segments[0].affine else None
                weight = getattr(self, f"weight_{index}")
                if self.forms[index] == "few":
                    out, sums[index] = few_channel_conv(table, *segments[0], affine, norms[0], weight, bias,
                                                        out_dtype, launch.stats, self.pdl)
                else:
                    out, sums[index] = fused_conv(table, *segments[0], *second, affine, norms[0],
                                                  norms[1] if len(norms) == 2 else None, weight, bias, out_dtype,
                                                  launch.stats, self.pdl)
            outputs.append(out)
        return outputs[-1]

    def _run_persistent(self, x: torch.Tensor) -> torch.Tensor:
        """The plan as one persistent kernel: model.persistent_kernel's operator on model.persistent_network's spec
        (data: the kernel is made from it where it runs, for that GPU)."""
        from model.persistent_kernel import persistent
        from model.persistent_network import persistent_spec
        if self._persistent_spec is None:
            self._persistent_spec = persistent_spec(self, self.dtype)
        spec, names = self._persistent_spec
        return persistent(x.float().contiguous(), self.affine, [self.get_buffer(name) for name in names], spec)
