"""The training step replayed as a CUDA graph (model.training_step) computes what the eager step computes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameStore
from model.losses import LossWeights
from model.networks import NetworkSpec, build_network
from model.training import Frames, TrainSettings, fit
from model.training_step import (COSINE_FLOOR, WARMUP_STEPS, GraphedStep, adam, eager_step, learning_rate,
                                 set_learning_rate)
from pipeline.core.errors import PipelineError
from pipeline.train import main as train_main
from model_meshes import identity_subdivider

SPEC = FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")


def _problem(grid, device):
    vertices, faces, mesh = grid
    generator = torch.Generator().manual_seed(5)
    base = torch.as_tensor(vertices, dtype=torch.float32)
    positions = base + 0.05 * torch.randn(8, *base.shape, generator=generator)
    capsule_a = torch.tensor([[0.2, 0.0, 0.1], [0.5, 0.3, -0.1]]).expand(8, 2, 3)
    store = FrameStore(positions, identity_subdivider(positions.shape[1], device),
                       torch.tensor([0, 0, 1, 2, 4, 4, 5, 6]), capsule_a, capsule_a + 0.3,
                       torch.tensor([0.05, 0.1]), torch.tensor([0.08, 0.02]),
                       torch.tensor([[0.0, -1.0, 0.0]]).expand(8, 3), 0.1)
    on = {f.name: getattr(store, f.name) for f in dataclasses.fields(store)}
    store = FrameStore(**{k: v.to(device) if isinstance(v, torch.Tensor) else v for k, v in on.items()})
    targets = 0.01 * torch.sin(7 * positions)
    return mesh.to(device), Frames(store, targets.to(device), torch.as_tensor(faces, device=device))


def _model(grid, device) -> FeatureRegressor:
    torch.manual_seed(0)
    net = build_network(NetworkSpec("D8 D D8", "RC7", in_channels=SPEC.channels))
    return FeatureRegressor(net, SPEC, grid[1], grid[0], output_scale=0.01).to(device)


def test_the_eager_step_is_one_adam_step_on_the_batch_loss(grid):
    mesh, frames = _problem(grid, "cpu")
    model, reference = _model(grid, "cpu"), _model(grid, "cpu")
    weights, ids = LossWeights(1.0, 1.0, 0.1), torch.tensor([1, 4, 6])
    values = eager_step(model, mesh, frames, adam(model, 1e-3, graphed=False), weights)(ids)
    optimizer = torch.optim.Adam(reference.parameters(), lr=1e-3, betas=(0.9, 0.999), eps=1e-8)
    loss, terms = frames.batch_loss(reference, mesh, ids, weights)
    loss.backward()
    optimizer.step()
    torch.testing.assert_close(values, torch.stack([loss, terms["l1"], terms["l2"], terms["normal"]]).detach(),
                               rtol=0, atol=0)
    for name, value in reference.state_dict().items():
        torch.testing.assert_close(model.state_dict()[name], value, rtol=0, atol=0)


def test_a_graph_needs_a_cuda_device():
    with pytest.raises(ValueError, match="CUDA device"):
        GraphedStep(lambda ids: ids, 3, torch.device("cpu"))
    with pytest.raises(PipelineError, match="needs a CUDA device"):
        train_main(["d.h5", "o.h5", "m.pt", "l.h5", "--arch", "D8 D D8", "--cuda-graph", "true"])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA device")
@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_graph_replay_trains_as_the_eager_step_does(grid, schedule):
    """7 training frames at batch 3: two full batches and a partial one per epoch, so over 4 epochs the graph is
    warmed up, captured, replayed, and interleaved with eager partial batches on the same gradient tensors; with
    the cosine rate the captured step reads a rate tensor the schedule rewrites every step."""
    torch.use_deterministic_algorithms(True)
    mesh, frames = _problem(grid, "cuda")
    train, test = torch.arange(7, device="cuda"), torch.tensor([7], device="cuda")
    histories, states = [], []
    for graphed in (False, True):
        model = _model(grid, "cuda")
        settings = TrainSettings(4, 3, 1e-3, LossWeights(1.0, 1.0, 0.1), 0, graphed, lr_schedule=schedule)
        histories.append(fit(model, mesh, frames, train, test, settings).batch_total)
        states.append(model.state_dict())
    assert len(histories[1]) == 12 and 2 * 4 > WARMUP_STEPS
    np.testing.assert_allclose(histories[1], histories[0], rtol=1e-5)
    for name, value in states[0].items():
        torch.testing.assert_close(states[1][name], value, rtol=1e-5, atol=1e-7)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a CUDA device")
def test_graphed_input_noise_draws_fresh_noise_each_replay_and_repeats_run_to_run(grid):
    """Noise drawn inside the captured graph: each replay must draw anew, and the same seed give the same run.
    One batch of the same 3 frames every epoch at a rate of ~0: only the noise can change the loss."""
    torch.use_deterministic_algorithms(True)
    mesh, frames = _problem(grid, "cuda")
    train, test = torch.arange(3, device="cuda"), torch.tensor([7], device="cuda")
    runs = {}
    for noise, run in ((0.5, "a"), (0.5, "b"), (0.0, "none")):
        torch.manual_seed(0)
        model = _model(grid, "cuda")
        settings = TrainSettings(WARMUP_STEPS + 8, 3, 1e-12, LossWeights(1.0, 0.0, 0.0), 0, True,
                                 input_noise=noise)
        runs[run] = np.asarray(fit(model, mesh, frames, train, test, settings).batch_total)
    np.testing.assert_array_equal(runs["a"], runs["b"])
    replayed, quiet = runs["a"][WARMUP_STEPS + 1:], runs["none"][WARMUP_STEPS + 1:]
    assert np.isfinite(replayed).all()
    assert np.std(quiet) < 1e-5 * np.mean(quiet) and np.std(replayed) > 1e-3 * np.mean(replayed)


def test_cosine_rate_runs_from_lr_to_the_floor_and_constant_stays():
    lr, total = 2e-3, 101
    rates = [learning_rate("cosine", lr, step, total) for step in range(total)]
    assert rates[0] == pytest.approx(lr) and rates[-1] == pytest.approx(COSINE_FLOOR * lr)
    assert rates[50] == pytest.approx(lr * (1 + COSINE_FLOOR) / 2)          # half way: the mean of the two ends
    assert all(a > b for a, b in zip(rates, rates[1:]))
    assert learning_rate("constant", lr, 77, total) == lr
    with pytest.raises(ValueError, match="unknown learning-rate schedule 'step'"):
        learning_rate("step", lr, 0, total)


def test_set_learning_rate_writes_a_tensor_rate_in_place():
    """A graphed step reads its rate from the tensor it captured: the schedule must write into that tensor."""
    parameter = torch.nn.Parameter(torch.zeros(3))
    optimizer = torch.optim.Adam([parameter], lr=torch.tensor(1e-3))
    captured = optimizer.param_groups[0]["lr"]
    set_learning_rate(optimizer, 5e-4)
    assert optimizer.param_groups[0]["lr"] is captured and float(captured) == pytest.approx(5e-4)
    plain = torch.optim.Adam([parameter], lr=1e-3)
    set_learning_rate(plain, 5e-4)
    assert plain.param_groups[0]["lr"] == 5e-4
