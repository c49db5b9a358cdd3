"""The feature-input regressor: normalisation statistics against numpy over every frame at once, and a whole
network (features, local frames, mesh CNN) that turns exactly with a rigid motion of everything it sees."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import model.feature_regressor as feature_regressor
from model.feature_regressor import FeatureRegressor, FeatureSpec, mean_square, store_statistics
from model.features import FrameBatch, FrameStore, InputFeatures, previous_frames
from model.networks import NetworkSpec, build_network
from model_meshes import identity_subdivider


def _store(vertices: np.ndarray, n_frames: int = 9) -> FrameStore:
    """Frames of a waving, drifting sheet in two sequences, one capsule under it, gravity along -y."""
    rng = np.random.default_rng(2)
    t = np.arange(n_frames)[:, None, None]
    noise = 0.02 * rng.normal(size=(n_frames, *vertices.shape))
    positions = vertices[None] + 0.05 * np.sin(t + 3 * vertices[None, :, :1]) + noise
    capsule = np.broadcast_to(np.array([[[0.0, -1.0, 0.0]]]), (n_frames, 1, 3))
    t32 = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)      # noqa: E731
    previous = previous_frames(np.array([0] * 4 + [1] * (n_frames - 4)))
    return FrameStore(t32(positions), identity_subdivider(positions.shape[1]), torch.as_tensor(previous),
                      t32(capsule), t32(capsule + [1.0, 0.0, 0.0]),
                      torch.tensor([0.3]), torch.tensor([0.2]), t32(np.tile([0.0, -1.0, 0.0], (n_frames, 1))), 0.1)


def test_store_statistics_centre_channels_and_scale_each_feature_as_one(grid, monkeypatch):
    vertices, faces, _ = grid
    store = _store(vertices)
    features = InputFeatures.of(FeatureSpec(("velocity", "body", "gravity", "rest_position")), faces, vertices)
    ids = torch.tensor([0, 2, 3, 5, 6, 8])
    monkeypatch.setattr(feature_regressor, "STATISTICS_FRAMES", 4)       # measured on frames 0, 3, 5, 8
    offset, scale = store_statistics(features, store, ids, batch_size=3)
    every = features(store.batch(torch.tensor([0, 3, 5, 8]))).double().numpy().reshape(-1, features.channels)
    np.testing.assert_allclose(offset, every.mean(axis=0), rtol=1e-5, atol=1e-6)
    centred = every - every.mean(axis=0)
    expected = [np.sqrt(np.mean(centred[:, a:b] ** 2)) for a, b in ((0, 3), (3, 7), (7, 10), (10, 13))]
    np.testing.assert_allclose(scale[[0, 3, 7, 10]], [expected[0], expected[1], 1.0, expected[3]], rtol=1e-5)
    assert expected[2] < 1e-6                           # gravity never varies: scale 1, not 0
    assert torch.all(scale[:3] == scale[0]) and torch.all(scale[3:7] == scale[3])   # one scale per feature


def test_normalise_gives_unit_inputs_and_the_target_rms(grid):
    vertices, faces, _ = grid
    store = _store(vertices)
    spec = FeatureSpec(("position", "laplacian"), "dataset", "local", "edge")
    model = FeatureRegressor(build_network(NetworkSpec("D4 D D6", "RC7", in_channels=spec.channels)), spec, faces,
                             vertices)
    ids, targets = torch.arange(9), 0.01 * torch.randn(9, len(vertices), 3)
    model.normalise(store, ids, targets)
    encoded, frames = model.encode(store.batch(ids))
    torch.testing.assert_close(encoded.mean(dim=(0, 1)), torch.zeros(6), atol=1e-5, rtol=0)
    torch.testing.assert_close(encoded[..., :3].square().mean(), torch.tensor(1.0), rtol=1e-4, atol=0)
    assert frames.shape == (9, len(vertices), 3, 3)
    assert model.output_scale == pytest.approx(float(targets.square().mean().sqrt()), rel=1e-6)


@pytest.mark.parametrize("fields, message", [
    ({"inputs": ()}, "distinct names"), ({"inputs": ("position", "position")}, "distinct names"),
    ({"inputs": ("speed",)}, "distinct names"), ({"input_frame": "world"}, "input_frame"),
    ({"output_frame": "torso"}, "output_frame"), ({"frame_tangent": "up"}, "frame_tangent"),
    ({"inputs": ("normal",), "input_frame": "local"}, "normal"),
])
def test_feature_spec_refuses_what_cannot_be_built(fields, message):
    with pytest.raises(ValueError, match=message):
        FeatureSpec(**fields)


def _inputs(x, previous, a, b, gravity) -> FrameBatch:
    t = lambda array: torch.as_tensor(array, dtype=torch.float64)[None]      # noqa: E731
    radii = torch.tensor([0.2, 0.1], dtype=torch.float64)
    return FrameBatch(t(x), t(previous), t(previous), t(a), t(b), radii, radii, t(gravity), 0.1)


def test_local_inputs_and_outputs_make_the_whole_regressor_rotation_equivariant(grid):
    vertices, faces, mesh = grid
    rng = np.random.default_rng(0)
    x = vertices + 0.05 * rng.normal(size=vertices.shape)
    previous = x + 0.01 * rng.normal(size=x.shape)
    a, b = np.array([[0.3, -0.5, 0.2], [0.6, 0.4, 0.6]]), np.array([[0.5, -0.4, 0.8], [0.9, 0.6, 0.2]])
    gravity = np.array([0.0, -0.6, -0.8])
    spec = FeatureSpec(("velocity", "body", "laplacian", "strain", "gravity"), "local", "local", "gravity")
    net = build_network(NetworkSpec("D4 D D6", "RC7", in_channels=spec.channels))
    model = FeatureRegressor(net, spec, faces, vertices, output_scale=0.1).double().eval()
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
    with pytest.raises(ValueError, match="input channels"):
        FeatureRegressor(build_network(NetworkSpec("D4 D D6", "RC7")), FeatureSpec(("normal", "body")), faces,
                         vertices)


def test_encoded_inputs_can_be_cached_and_decoded_later(grid):
    vertices, faces, mesh = grid
    store = _store(vertices)
    for frame in ("dataset", "local"):
        spec = FeatureSpec(("normal", "laplacian"), "dataset", frame)
        net = build_network(NetworkSpec("D4 D D6", "RC7", in_channels=spec.channels))
        model = FeatureRegressor(net, spec, faces, vertices, output_scale=0.1).eval()
        inputs = store.batch(torch.tensor([1, 5]))
        encoded, frames = model.encode(inputs)
        assert (frames is None) == (frame == "dataset")
        with torch.no_grad():
            torch.testing.assert_close(model.decode(encoded, frames, mesh), model(inputs, mesh))


def test_mean_square_of_the_chosen_frames_batch_by_batch_matches_numpy():
    targets = torch.randn(11, 7, 3)
    ids = torch.tensor([9, 0, 3, 3, 10, 5, 1])       # any order, repeats count twice, batches of 3 cross them
    expected = np.mean(np.square(targets.double().numpy()[ids.numpy()]))
    assert mean_square(targets, ids, batch_size=3) == pytest.approx(expected, rel=1e-12)
    assert mean_square(targets, ids[:0]) == 0.0


def test_input_noise_has_the_asked_spread_in_training_and_none_otherwise():
    torch.manual_seed(0)
    z = torch.randn(4, 5000, 6)
    noisy = feature_regressor.with_input_noise(z, 0.2, training=True)
    assert abs(float((noisy - z).std()) - 0.2) < 0.005 and abs(float((noisy - z).mean())) < 0.005
    assert feature_regressor.with_input_noise(z, 0.2, training=False) is z
    assert feature_regressor.with_input_noise(z, 0.0, training=True) is z
