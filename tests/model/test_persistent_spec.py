"""The persistent kernel's spec (model.persistent_network writes it, model.persistent_spec checks it,
model.persistent_kernel makes the kernel's text from it): a real network's spec passes and gives one grid barrier
between phases; a spec from elsewhere (an exported program is a file) that is anything but numbers, flags and
known keys is refused before any text is made from it. The check needs no Triton (it runs in CI); the text does.
The kernel's results against the plan are tests/model/test_fused_network.py's ("persistent" variants)."""
from __future__ import annotations

import copy
import json

import pytest
import torch

from model.fused_network import FusedNetwork
from model.persistent_network import persistent_spec
from model.persistent_spec import checked_spec
from test_fused_network import ARCHS, _case


@pytest.fixture(scope="module")
def spec_and_buffers():
    net, mesh, offset, scale, _ = _case("max", ARCHS[1])
    network = FusedNetwork(net, mesh, offset, scale, 0.3, torch.bfloat16, persistent=True)
    text, buffers = persistent_spec(network, torch.bfloat16)
    return network, text, buffers


def test_a_networks_spec_passes_and_names_its_buffers(spec_and_buffers):
    network, text, buffers = spec_and_buffers
    spec = checked_spec(text, len(buffers))
    assert len(spec["steps"]) == len(network.plan) and spec["hidden_dtype"] == "bfloat16"
    assert all(name in dict(network.named_buffers()) for name in buffers) and len(set(buffers)) == len(buffers)
    with pytest.raises(ValueError, match="persistent spec"):       # one buffer fewer than it names
        checked_spec(text, len(buffers) - 1)


def test_the_kernel_text_has_one_barrier_between_phases_and_depends_on_the_grid(spec_and_buffers):
    pytest.importorskip("triton", reason="the kernel's text is made by the Triton module (PyTorch's CUDA wheels)")
    from model.persistent_kernel import kernel_source

    _, text, buffers = spec_and_buffers
    spec = checked_spec(text, len(buffers))
    for programs in (1, 132):
        source = kernel_source(spec, len(buffers), programs)
        assert source.count("_grid_barrier(") == len(spec["phases"]) - 1
        assert source.count("_tile_of(") == len(spec["steps"])
    # The grid changes the tiles, so the text is made where the kernel runs.
    assert kernel_source(spec, len(buffers), 1) != kernel_source(spec, len(buffers), 132)


def _changed(text: str, change) -> str:
    spec = copy.deepcopy(json.loads(text))
    change(spec)
    return json.dumps(spec)


def _first(spec: dict, kind: str) -> dict:
    return next(step for step in spec["steps"] if step["kind"] == kind)


HOSTILE = {
    "text where a number goes": lambda s: s["steps"][0].update(rows="1); import os; os.system('x') #"),
    "a flag that is a number": lambda s: _first(s, "gather").update(stats=1),
    "a number that is a flag": lambda s: s["steps"][0].update(rows=True),
    "a float": lambda s: s.update(sums_stride=32.5),
    "a negative count": lambda s: s["steps"][0].update(cols=-3),
    "a count past int32": lambda s: s["steps"][0].update(rows=2 ** 31),
    "an unknown key": lambda s: s["steps"][0].update(call="_conv_tile()"),
    "a missing key": lambda s: s["steps"][0].pop("rows"),
    "an unknown kind": lambda s: s["steps"][0].update(kind="exec"),
    "a source after its step": lambda s: _first(s, "gather")["inputs"][0].update(source=len(s["steps"])),
    "a buffer that is not there": lambda s: _first(s, "gather").update(weight=10 ** 6),
    "three inputs": lambda s: _first(s, "gather")["inputs"].extend([{}, {}]),
    "a step in no phase": lambda s: s["phases"][-1].pop(),
    "a phase of names": lambda s: s["phases"][0].append("import os"),
    "a version that is a flag": lambda s: s.update(version=True),
    "a dtype that is a list": lambda s: s.update(hidden_dtype=["bfloat16"]),
    "a step beside its source": lambda s: s.update(phases=[[i for phase in s["phases"] for i in phase]]),
    "another version": lambda s: s.update(version=2),
    "another dtype": lambda s: s.update(hidden_dtype="object"),
}


@pytest.mark.parametrize("change", HOSTILE.values(), ids=HOSTILE.keys())
def test_a_spec_that_is_anything_else_is_refused(spec_and_buffers, change):
    _, text, buffers = spec_and_buffers
    with pytest.raises(ValueError, match="persistent spec"):
        checked_spec(_changed(text, change), len(buffers))


def test_a_spec_that_is_not_an_object_is_refused(spec_and_buffers):
    _, _, buffers = spec_and_buffers
    for text in ("[]", "1", '"steps"', "{}", "{'steps': 1}"):
        with pytest.raises(ValueError, match="persistent spec"):
            checked_spec(text, len(buffers))
