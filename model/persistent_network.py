"""The fused network's whole plan in one launch: the plan as the spec of model.persistent_kernel's kernel.

A small network's frame (RC9 x/4 at 15k vertices) is ~45 dependent kernels of a few microseconds each, every one
at a kernel's floor (launch ramp, one partial wave, drain) plus ~1 us a graph node between them
(docs/performance.md, "Inference"). Here the plan's launches (model.fused_network: one step a convolution, a
pooling or a norm; every convolution gathering) become the steps of one kernel, grouped into phases
(`fused_network.plan_phases`: a step in the phase after its sources', so a skip connection's normalised copy runs
beside the pooling of the same value), a grid barrier between phases.

This module writes what the kernel needs as data (`persistent_spec`: each step's kind, shapes, flags and which
step or buffer it reads, JSON) and lists the network's buffers in the spec's numbering; model.persistent_kernel
turns a checked spec into the kernel on the GPU it runs on, behind one operator that torch.export keeps, so an
exported program carries the spec and the kernel module, not a kernel made for the exporting GPU.

The unfolded plan is the faster one here: a norm written once by its own step costs a barrier and a ~1 us pass,
where folded into the readers (`fold_norms`) it makes every gathering loop of the decoder 1.5-3x slower an iteration
(timestamps on an H200: docs/history/performance-log.md, "The persistent kernel's phases").
"""
from __future__ import annotations

import json

import torch

from model.fused_network import NETWORK_INPUT, FusedConv, Prepare, plan_phases
from model.persistent_spec import NETWORK_INPUT as SPEC_INPUT, SPEC_VERSION, SUMS_ALIGN

assert NETWORK_INPUT == SPEC_INPUT, "the plan and the spec number the network's input alike"


def persistent_spec(network, hidden: torch.dtype) -> tuple[str, list[str]]:
    """A FusedNetwork's plan (no products-first convolution) as model.persistent_kernel's spec (JSON text), and
    the names of the network's buffers the spec's buffer indices stand for, in order. `hidden`: the storage
    dtype of every step's output but the last (fp32)."""
    plan = network.plan
    buffers: list[str] = []

    def buffer(name: str) -> int:
        if name not in buffers:
            buffers.append(name)
        return buffers.index(name)

    vertices, channels, sums = [0] * len(plan), [0] * len(plan), {}
    offset = 0
    for index, launch in enumerate(plan):
        if isinstance(launch, FusedConv):
            vertices[index] = network.get_buffer(f"table_{launch.level}").shape[0]
            channels[index] = launch.weight.shape[1]
            if launch.stats:
                sums[index] = offset
                offset += -(-2 * channels[index] // SUMS_ALIGN) * SUMS_ALIGN
        else:
            vertices[index] = vertices[launch.source] if launch.rows is None else launch.rows.shape[0]
            channels[index] = launch.channels

    def source_shape(source: int, width: int) -> tuple[int, int]:
        if source == NETWORK_INPUT:
            return network.get_buffer("table_0").shape[0], width
        return vertices[source], channels[source]

    steps = []
    for index, launch in enumerate(plan):
        shape = {"rows": vertices[index], "cols": channels[index]}
        if isinstance(launch, Prepare):
            src_rows, src_channels = source_shape(launch.source, launch.channels)
            mapped = launch.rows is not None
            steps.append({"kind": "prepare", **shape, "source": launch.source, "src_rows": src_rows,
                          "src_channels": src_channels, "map": buffer(f"rows_{index}_0") if mapped else -1,
                          "map_width": launch.rows.shape[1] if mapped else 0, "sums": sums.get(launch.source, 0),
                          "normalize": bool(launch.normalize), "pool_max": bool(network.pool_max)})
            continue
        form = network.forms[index]
        if form not in ("few", "gather"):
            raise ValueError(f"the persistent kernel gathers every convolution; step {index} is '{form}'")
        inputs = []
        for number, segment in enumerate(launch.segments):
            src_rows, width = source_shape(segment.source, segment.channels)
            inputs.append({"source": segment.source, "src_rows": src_rows, "channels": width,
                           "map": buffer(f"rows_{index}_{number}") if segment.rows is not None else -1,
                           "sums": sums.get(segment.source, 0), "normalize": bool(segment.normalize)})
        step = {"kind": form, **shape, "table": buffer(f"table_{launch.level}"),
                "table_width": network.get_buffer(f"table_{launch.level}").shape[1],
                "weight": buffer(f"weight_{index}"), "bias": buffer(f"bias_{index}"), "sums": sums.get(index, 0),
                "affine": bool(launch.segments[0].affine), "stats": bool(launch.stats), "inputs": inputs}
        if form == "gather":
            step["precise"] = network.get_buffer(f"weight_{index}").dtype == torch.float32
        steps.append(step)
    spec = {"version": SPEC_VERSION, "hidden_dtype": str(hidden).removeprefix("torch."),
            "sums_stride": max(offset, SUMS_ALIGN), "steps": steps, "phases": plan_phases(plan)}
    return json.dumps(spec, separators=(",", ":")), buffers
