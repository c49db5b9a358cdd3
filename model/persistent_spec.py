"""The persistent kernel's spec: what model.persistent_network writes of a fused network's plan and
model.persistent_kernel makes the kernel from, as data (JSON: each step's kind, shapes, flags and which step or
buffer it reads, and the phases), and the check a spec passes before any kernel text is made from it. Plain
Python: the check runs (and is tested) without Triton, and the export's kernels package carries it."""
from __future__ import annotations

import json

SPEC_VERSION = 1
SUMS_ALIGN = 32                # floats: a step's norm sums start on a 128-byte line of their own
HIDDEN_DTYPE_NAMES = ("float32", "bfloat16")
LARGEST = 2 ** 31 - 1          # every count and offset of a spec fits an int32
# A spec's keys: a step's by kind, an input's (a convolution's segment), the whole spec's.
_STEP_INTS = {"prepare": ("rows", "cols", "source", "src_rows", "src_channels", "map", "map_width", "sums"),
              "few": ("rows", "cols", "table", "table_width", "weight", "bias", "sums"),
              "gather": ("rows", "cols", "table", "table_width", "weight", "bias", "sums")}
_STEP_BOOLS = {"prepare": ("normalize", "pool_max"), "few": ("affine", "stats"),
               "gather": ("affine", "stats", "precise")}
_INPUT_INTS = ("source", "src_rows", "channels", "map", "sums")
_INPUT_BOOLS = ("normalize",)
NETWORK_INPUT = -1             # a source that is the network's input x, not a step's output


def checked_spec(text: str, n_buffers: int) -> dict:
    """The spec in `text`, ValueError unless it is exactly a spec: known keys only, integers in [-1, 2^31) where
    an index may be absent and [0, 2^31) elsewhere, booleans, sources before their step, buffer indices below
    `n_buffers`, phases that hold every step once after each of its sources. What this guards is the kernel's
    text (nothing but these numbers and flags goes into it); that the shapes match the buffers is the program's
    own word, as for the other operators' tables (the runner's --fused: exports you made yourself)."""
    try:
        spec = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"persistent spec: not JSON ({err})") from None
    _keys(spec, {"version", "hidden_dtype", "sums_stride", "steps", "phases"}, "the spec")
    if type(spec["version"]) is not int or spec["version"] != SPEC_VERSION or not isinstance(
            spec["hidden_dtype"], str) or spec["hidden_dtype"] not in HIDDEN_DTYPE_NAMES:
        raise ValueError(f"persistent spec: version {spec['version']!r} or hidden dtype {spec['hidden_dtype']!r} "
                         f"unknown")
    _count(spec["sums_stride"], "sums_stride")
    steps = spec["steps"]
    if not isinstance(steps, list) or not steps:
        raise ValueError("persistent spec: no steps")
    for index, step in enumerate(steps):
        kind = step.get("kind") if isinstance(step, dict) else None
        if kind not in _STEP_INTS:
            raise ValueError(f"persistent spec: step {index} of unknown kind {kind!r}")
        inputs = ("inputs",) if kind != "prepare" else ()
        _keys(step, {"kind", *_STEP_INTS[kind], *_STEP_BOOLS[kind], *inputs}, f"step {index}")
        for key in _STEP_INTS[kind]:
            _count(step[key], f"step {index}'s {key}", lowest=-1 if key in ("source", "map") else 0)
        for key in _STEP_BOOLS[kind]:
            _flag(step[key], f"step {index}'s {key}")
        segments = [step] if kind == "prepare" else step["inputs"]
        most = 1 if kind == "few" else 2
        if kind != "prepare" and not (isinstance(segments, list) and 1 <= len(segments) <= most):
            raise ValueError(f"persistent spec: step {index} has {segments!r} as its inputs")
        for number, segment in enumerate(segments if kind != "prepare" else []):
            _keys(segment, {*_INPUT_INTS, *_INPUT_BOOLS}, f"step {index}'s input {number}")
            for key in _INPUT_INTS:
                _count(segment[key], f"step {index}'s input {number} {key}",
                       lowest=-1 if key in ("source", "map") else 0)
            _flag(segment["normalize"], f"step {index}'s input {number} normalize")
        for segment in segments:
            if segment["source"] >= index or segment["map"] >= n_buffers:
                raise ValueError(f"persistent spec: step {index} reads a later step or a missing buffer")
        if kind != "prepare" and max(step["table"], step["weight"], step["bias"]) >= n_buffers:
            raise ValueError(f"persistent spec: step {index} names a missing buffer")
    phases = spec["phases"]
    flat = [i for phase in phases for i in phase] if isinstance(phases, list) and all(
        isinstance(phase, list) for phase in phases) else None
    if flat is None or any(type(i) is not int for i in flat) or sorted(flat) != list(range(len(steps))):
        raise ValueError("persistent spec: the phases do not hold every step once")
    phase_of = {i: number for number, phase in enumerate(phases) for i in phase}
    for index, step in enumerate(steps):
        sources = [step["source"]] if step["kind"] == "prepare" else [s["source"] for s in step["inputs"]]
        if any(source >= 0 and phase_of[source] >= phase_of[index] for source in sources):
            raise ValueError(f"persistent spec: step {index} runs in the phase of one of its sources or before it")
    return spec


def _keys(value, keys: set[str], what: str) -> None:
    if not isinstance(value, dict) or set(value) != keys:
        raise ValueError(f"persistent spec: {what} must have exactly the keys {', '.join(sorted(keys))}")


def _count(value, what: str, lowest: int = 0) -> None:
    if type(value) is not int or not lowest <= value <= LARGEST:
        raise ValueError(f"persistent spec: {what} must be an integer from {lowest} to 2^31 - 1, got {value!r}")


def _flag(value, what: str) -> None:
    if type(value) is not bool:
        raise ValueError(f"persistent spec: {what} must be true or false, got {value!r}")
