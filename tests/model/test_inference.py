"""The fast inference path against the eager network on the fixture mesh with random weights and non-trivial
normalisations: the reordering is a relabelling, the folded fp32 path gives the eager output to 1e-5 of its
largest value, bf16 stays within a stated bound, and the whole learned path equals S x_low + eager."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameBatch
from model.inference import (FastNetwork, FastRegressor, FastUpsampler, UPSAMPLER_INPUTS, inverse_order,
                             locality_orders, needed_inputs, padded_stencil, reorder_hierarchy,
                             stencil_product)
from model.networks import NetworkSpec, build_network
from model_meshes import build_hierarchy, grid_mesh

FP32_TOLERANCE = 1e-5      # of the largest |eager| displacement
BF16_TOLERANCE = 5e-2      # measured 0.4-1 % on these random networks (printed by the test)
SPECS = [FeatureSpec(),
         FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity"),
         FeatureSpec(("position", "normal", "strain", "acceleration", "rest_position"), "dataset", "local", "edge")]


def _regressor(spec: FeatureSpec, vertices: np.ndarray, faces: np.ndarray, pool: str = "max") -> FeatureRegressor:
    net = build_network(NetworkSpec("D8 D16 D D16", "RC7", pool, in_channels=spec.channels))
    offset, scale = torch.randn(spec.channels), torch.rand(spec.channels) + 0.5
    return FeatureRegressor(net, spec, faces, vertices, offset, scale, 0.3).eval()


def _frames(vertices: np.ndarray, batch: int = 2) -> FrameBatch:
    rest = torch.as_tensor(vertices, dtype=torch.float32)
    moved = lambda x, size: x + size * torch.randn(batch, *rest.shape)  # noqa: E731
    positions = moved(rest, 0.05)
    previous = moved(positions, 0.01)
    return FrameBatch(positions, previous, moved(previous, 0.01), torch.randn(batch, 2, 3), torch.randn(batch, 2, 3),
                      torch.rand(2) + 0.1, torch.rand(2) + 0.1,
                      torch.nn.functional.normalize(torch.randn(batch, 3), dim=-1), 0.1)


def _relative(got: torch.Tensor, expected: torch.Tensor) -> float:
    return float((got - expected).abs().max() / expected.abs().max())


def _bandwidth(mesh) -> int:
    table = mesh.conv[0].numpy()
    rows = np.repeat(np.arange(len(table)), table.shape[1])[table.ravel() > 0]
    return int(np.abs(table.ravel()[table.ravel() > 0] - 1 - rows).max())


def test_reordering_is_a_relabelling_that_narrows_the_tables(grid):
    vertices, faces, _ = grid
    shuffle = np.random.default_rng(0).permutation(len(vertices))      # a badly numbered mesh
    faces = np.argsort(shuffle)[faces]
    mesh = build_hierarchy(faces, len(vertices), 7, 5)
    orders = locality_orders(mesh)
    reordered = reorder_hierarchy(mesh, orders)
    assert [sorted(o.tolist()) for o in orders] == [list(range(n)) for n in mesh.vertex_counts]
    assert _bandwidth(reordered) < _bandwidth(mesh) / 2
    net = build_network(NetworkSpec("D8 D16 D D16", "RC7", "avg"))
    x = torch.randn(1, len(vertices), 3)
    with torch.no_grad():
        expected = net(x, mesh)[:, orders[0]]
        torch.testing.assert_close(net(x[:, orders[0]], reordered), expected, rtol=1e-5, atol=1e-6)
    assert np.array_equal(inverse_order(orders[0])[orders[0]], np.arange(len(vertices)))


@pytest.mark.parametrize("pool", ["max", "avg"])
@pytest.mark.parametrize("spec", SPECS, ids=["positions", "body_relative", "local_output"])
def test_fast_regressor_gives_the_eager_output(grid, spec, pool):
    vertices, faces, mesh = grid
    model = _regressor(spec, vertices, faces, pool)
    frames = _frames(vertices)
    with torch.no_grad():
        expected = model(frames, mesh)
        fast = _relative(FastRegressor(model, mesh)(frames), expected)
        bf16 = _relative(FastRegressor(model, mesh, torch.bfloat16)(frames), expected)
    print(f"{spec.inputs} {pool}: fp32 {fast:.1e}, bf16 {bf16:.1e} of the largest displacement")
    assert fast < FP32_TOLERANCE
    assert bf16 < BF16_TOLERANCE


def test_folding_handles_padding_slots_and_a_batch_is_its_frames(grid):
    """The boundary vertices' tables hold padding slots, where a folded offset would leak if done naively; and
    frames of a batch do not mix (instance norm is per frame)."""
    vertices, faces, mesh = grid
    assert (mesh.conv[0] == 0).any()
    model = _regressor(FeatureSpec(("position",)), vertices, faces)
    model.input_offset.fill_(5.0)                      # far from zero: a leak would dominate
    fast = FastRegressor(model, mesh)
    frames = _frames(vertices, batch=3)
    with torch.no_grad():
        together = fast(frames)
        assert _relative(together, model(frames, mesh)) < FP32_TOLERANCE
        single = FrameBatch(frames.positions[1:2], frames.previous[1:2], frames.before_previous[1:2],
                            frames.capsule_a[1:2], frames.capsule_b[1:2], frames.radius_a, frames.radius_b,
                            frames.gravity[1:2], frames.frame_time)
        torch.testing.assert_close(fast(single)[0], together[1], rtol=1e-5, atol=1e-6)


def test_fast_network_refuses_the_decoder(grid):
    _, _, mesh = grid
    decoder = build_network(NetworkSpec("U8 U U3", "RC7", in_channels=5, coarse_vertices=mesh.vertex_counts[3]))
    with pytest.raises(ValueError, match="encoder-decoder only"):
        FastNetwork(decoder, mesh, torch.zeros(5), torch.ones(5), 1.0)


def test_padded_stencil_and_its_product_are_the_sparse_product():
    low, low_faces = grid_mesh(4, 5)
    subdivision, _ = loop_subdivide(low, low_faces, 2)
    columns, weights = padded_stencil(subdivision)
    x = np.random.default_rng(1).normal(size=(len(low), 3))
    np.testing.assert_allclose((x[columns] * weights[..., None]).sum(axis=1), subdivision @ x, rtol=1e-6,
                               atol=1e-6)
    frames = np.random.default_rng(2).normal(size=(3, len(low), 4))       # a batch, channels other than xyz
    got = stencil_product(torch.as_tensor(columns), torch.as_tensor(weights), torch.as_tensor(frames))
    assert got.dtype == torch.float64 and got.shape == (3, subdivision.shape[0], 4)
    np.testing.assert_allclose(got.numpy(), np.stack([subdivision @ f for f in frames]), rtol=1e-12, atol=1e-12)
    assert stencil_product(torch.as_tensor(columns), torch.as_tensor(weights), torch.zeros(0, len(low), 3)).shape == \
        (0, subdivision.shape[0], 3)


def test_upsampler_is_subdivision_plus_the_eager_displacement():
    low, low_faces = grid_mesh(4, 5)
    subdivision, faces = loop_subdivide(low, low_faces, 1)
    high = subdivision @ low
    mesh = build_hierarchy(faces, len(high), 7, 4)
    spec = SPECS[1]
    model = _regressor(spec, high, faces)
    upsampler = FastUpsampler(FastRegressor(model, mesh), subdivision)
    frames = _frames(low, batch=2)
    smooth = lambda x: torch.as_tensor(np.stack([subdivision @ f for f in x.double().numpy()]),  # noqa: E731
                                       dtype=torch.float32)
    with torch.no_grad():
        expected = model(FrameBatch(smooth(frames.positions), smooth(frames.previous), None, frames.capsule_a,
                                    frames.capsule_b, frames.radius_a, frames.radius_b, frames.gravity, 0.1), mesh)
        got = upsampler(frames.positions, frames.previous, None, frames.capsule_a, frames.capsule_b,
                        frames.radius_a, frames.radius_b, frames.gravity, torch.tensor(0.1))
    assert _relative(got - smooth(frames.positions), expected) < FP32_TOLERANCE
    assert needed_inputs(model) == ("low_positions", "low_previous", "capsule_a", "capsule_b", "radius_a",
                                    "radius_b", "gravity", "frame_time")


@pytest.mark.parametrize("spec, inputs", [
    (FeatureSpec(), ("low_positions",)),
    (FeatureSpec(("position", "laplacian"), "local", "dataset", "gravity"), ("low_positions", "gravity")),
    (FeatureSpec(("acceleration",), "dataset", "local", "edge"),
     ("low_positions", "low_previous", "low_before_previous", "frame_time")),
])
def test_needed_inputs_follow_the_features(grid, spec, inputs):
    vertices, faces, _ = grid
    assert needed_inputs(_regressor(spec, vertices, faces)) == inputs
    assert set(inputs) <= set(UPSAMPLER_INPUTS)
