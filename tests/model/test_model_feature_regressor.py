"""The feature-input regressor: normalisation statistics by hand, and a whole network (features, local frames,
mesh CNN) that turns exactly with a rigid motion of everything it sees."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from model.feature_regressor import FeatureRegressor, feature_statistics
from model.features import FrameInputs, InputFeatures
from model.networks import NetworkSpec, build_network


def test_feature_statistics_centre_channels_and_scale_each_feature_as_one():
    features = torch.randn(4, 10, 5, dtype=torch.float64) * torch.tensor([1.0, 2.0, 3.0, 5.0, 0.0],
                                                                          dtype=torch.float64) + 7.0
    offset, scale = feature_statistics(features, [3, 1, 1])
    normalised = (features - offset) / scale
    torch.testing.assert_close(normalised.mean(dim=(0, 1)), torch.zeros(5, dtype=torch.float64))
    assert torch.isclose(normalised[..., :3].square().mean(), torch.tensor(1.0, dtype=torch.float64))
    assert torch.isclose(normalised[..., 3].square().mean(), torch.tensor(1.0, dtype=torch.float64))
    assert scale[0] == scale[1] == scale[2] and scale[4] == 1.0            # one scale per feature; constant: 1


def _inputs(x, previous, a, b, gravity) -> FrameInputs:
    t = lambda array: torch.as_tensor(array, dtype=torch.float64)[None]      # noqa: E731
    radii = torch.tensor([0.2, 0.1], dtype=torch.float64)
    return FrameInputs(t(x), t(previous), t(previous), t(a), t(b), radii, radii, t(gravity), 0.1)


def test_local_inputs_and_outputs_make_the_whole_regressor_rotation_equivariant(grid):
    vertices, faces, mesh = grid
    rng = np.random.default_rng(0)
    x = vertices + 0.05 * rng.normal(size=vertices.shape)
    previous = x + 0.01 * rng.normal(size=x.shape)
    a, b = np.array([[0.3, -0.5, 0.2], [0.6, 0.4, 0.6]]), np.array([[0.5, -0.4, 0.8], [0.9, 0.6, 0.2]])
    gravity = np.array([0.0, -0.6, -0.8])
    features = InputFeatures(("velocity", "body", "laplacian", "strain", "gravity"), faces, vertices,
                             local_inputs=True, frame_tangent="gravity")
    net = build_network(NetworkSpec("D4 D D6", "RC7", in_channels=features.channels))
    model = FeatureRegressor(net, features, torch.zeros(features.channels), torch.ones(features.channels), 0.1,
                             output_frame="local").double().eval()
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    rotation = q * np.sign(np.diag(r)) * np.sign(np.linalg.det(q))
    move = lambda p: p @ rotation.T + np.array([1.0, -2.0, 0.5])           # noqa: E731
    with torch.no_grad():
        original = model(_inputs(x, previous, a, b, gravity), mesh)
        moved = model(_inputs(move(x), move(previous), move(a), move(b), gravity @ rotation.T), mesh)
    torch.testing.assert_close(moved, original @ torch.as_tensor(rotation).T)
    assert original.abs().max() > 1e-3


def test_channel_counts_must_agree(grid):
    vertices, faces, _ = grid
    features = InputFeatures(("normal", "body"), faces, vertices)
    with pytest.raises(ValueError, match="input channels"):
        FeatureRegressor(build_network(NetworkSpec("D4 D D6", "RC7")), features, torch.zeros(7), torch.ones(7), 1.0)


def test_encoded_inputs_can_be_cached_and_decoded_later(grid):
    vertices, faces, mesh = grid
    rng = np.random.default_rng(1)
    x = vertices + 0.05 * rng.normal(size=vertices.shape)
    features = InputFeatures(("normal", "laplacian"), faces, vertices)
    net = build_network(NetworkSpec("D4 D D6", "RC7", in_channels=features.channels))
    inputs = _inputs(x, x, np.zeros((2, 3)), np.ones((2, 3)), np.array([0.0, -1.0, 0.0]))
    offset, scale = feature_statistics(features.double()(inputs), features.groups())
    for frame in ("dataset", "local"):
        model = FeatureRegressor(net, features, offset, scale, 0.1, frame).double().eval()
        encoded, frames = model.encode(inputs)
        assert (frames is None) == (frame == "dataset")
        torch.testing.assert_close(encoded.square().mean(), torch.tensor(1.0, dtype=torch.float64))
        with torch.no_grad():
            torch.testing.assert_close(model.decode(encoded, frames, mesh), model(inputs, mesh))
