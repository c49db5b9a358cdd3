"""The decoder tasks' regressor (model.tasks): fixed normalisation from the training frames, the displacement
scaled back, the decoder's parameters only, and one training loop shared with the upsampling."""
import numpy as np
import torch

from model.losses import LossWeights
from model.networks import NetworkSpec, build_network
from model.tasks import VectorRegressor, VectorSpec, VectorStore
from model.training import Frames, TrainSettings, fit, split_errors


def decoder_on(mesh, n_inputs: int):
    spec = NetworkSpec("U8 U U4 U3", "RC7", in_channels=n_inputs, coarse_vertices=mesh.vertex_counts[4])
    return build_network(spec)


def test_inputs_are_centred_and_scaled_per_scalar_from_the_training_frames_only(grid):
    _, _, mesh = grid
    values = torch.randn(20, 5, dtype=torch.float64) * torch.tensor([1.0, 10.0, 0.1, 3.0, 0.0]) + 4.0
    values[15:] += 1000.0                                       # frames outside the training ids: not looked at
    train = torch.arange(15)
    targets = torch.randn(20, 42, 3) * 0.02
    targets[15:] *= 100.0                                      # nor are their targets
    model = VectorRegressor(decoder_on(mesh, 5), VectorSpec(("pose",)))
    model.normalise(VectorStore(torch.zeros(20, 42, 3), values.float()), train, targets)
    seen = values[:15].numpy()
    np.testing.assert_allclose(model.input_offset.numpy(), seen.mean(axis=0), rtol=1e-6)
    expected_scale = np.where(seen.std(axis=0) > 0, seen.std(axis=0), 1.0)    # a constant scalar keeps scale 1
    np.testing.assert_allclose(model.input_scale.numpy(), expected_scale, rtol=1e-5)
    assert float(model.output_scale) == np.float32(np.sqrt(np.mean(np.square(targets[train].double().numpy()))))
    # the normalisation is buffers: the count is the decoder's alone
    assert sum(p.numel() for p in model.parameters()) == model.net.parameter_count()


def test_the_shared_training_loop_fits_a_decoder_task_below_its_predictor(grid):
    vertices, faces, mesh = grid
    rng = np.random.default_rng(0)
    pose = torch.as_tensor(rng.normal(size=(24, 4)), dtype=torch.float32)
    predictor = torch.as_tensor(np.repeat(vertices[None], 24, axis=0), dtype=torch.float32)
    # A displacement that depends on the input: a bulge scaled by the first scalar, plus a fixed sag.
    bulge = torch.as_tensor(np.exp(-np.square(vertices - vertices.mean(axis=0)).sum(axis=1)), dtype=torch.float32)
    targets = torch.zeros(24, 42, 3)
    targets[..., 2] = 0.05 * pose[:, :1] * bulge - 0.03
    frames = Frames(VectorStore(predictor, pose), targets, torch.as_tensor(faces, dtype=torch.int64))
    model = VectorRegressor(decoder_on(mesh, 4), VectorSpec(("pose",)))
    train, test = torch.arange(20), torch.arange(20, 24)
    model.normalise(frames.store, train, targets)
    weights = LossWeights(1.0, 1.0, 0.0)
    fit(model, mesh, frames, train, test, TrainSettings(30, 3, 1e-3, weights, 0), on_notice=lambda _: None)
    network = split_errors(lambda batch: model(batch, mesh), frames, train, 8, weights)
    alone = split_errors(lambda batch: torch.zeros_like(batch.positions), frames, train, 8, weights)
    assert network["l1"] < 0.5 * alone["l1"]
