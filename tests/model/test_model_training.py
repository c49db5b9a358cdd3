"""The training loop: resuming from a checkpoint, refusing stale ones, and split-wide error figures."""
from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameStore
from model.losses import LossWeights
from model.networks import NetworkSpec, build_network
import model.training
from model.training import CheckpointError, Frames, TrainSettings, fit, split_errors
from model.training_step import learning_rate, set_learning_rate
from model_meshes import identity_subdivider


def _problem(grid):
    vertices, faces, mesh = grid
    generator = torch.Generator().manual_seed(3)
    base = torch.as_tensor(vertices, dtype=torch.float32)
    inputs = base + 0.05 * torch.randn(7, *base.shape, generator=generator)
    targets = 0.01 * torch.sin(7 * inputs)
    no_body = torch.zeros(len(inputs), 0, 3)
    store = FrameStore(inputs, identity_subdivider(inputs.shape[1]), torch.arange(len(inputs)), no_body, no_body,
                       torch.zeros(0), torch.zeros(0),
                       torch.tensor([[0.0, -1.0, 0.0]]).expand(len(inputs), 3), 0.1)
    return mesh, Frames(store, targets, torch.as_tensor(faces))


def _model(grid) -> FeatureRegressor:
    torch.manual_seed(0)
    net = build_network(NetworkSpec("D8 D D8", "RC7"))
    return FeatureRegressor(net, FeatureSpec(("position",)), grid[1], grid[0], output_scale=0.01)


def _stored(state: dict) -> dict:
    """A checkpoint state after a trip through a file read with weights_only=True (tensors and plain values:
    anything else in the state would fail to load here)."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


@pytest.mark.parametrize("noise, schedule", [(0.0, "constant"), (0.3, "constant"), (0.0, "cosine")])
def test_resumed_training_equals_uninterrupted(grid, noise, schedule):
    """With input noise too: the checkpoint carries the noise generator's state (without it the resumed run's
    draws start from _model's seed, and its steps differ from the uninterrupted run's). With a cosine rate the
    resumed steps take the rates of their place in the whole run."""
    mesh, frames = _problem(grid)
    train_ids, test_ids = torch.arange(6), torch.tensor([6])
    settings = TrainSettings(epochs=4, input_noise=noise, lr_schedule=schedule)
    saved, notices = [], []
    straight = _model(grid)     # the uninterrupted run; its checkpoint after epoch 2 stands for a killed run's
    reference = fit(straight, mesh, frames, train_ids, test_ids, settings,
                    save_checkpoint=lambda state: saved.append(_stored(state)))
    resumed = _model(grid)
    history = fit(resumed, mesh, frames, train_ids, test_ids, settings, resume_from=saved[1],
                  on_notice=notices.append)
    assert len(saved) == 4 and history.resumed_from_epoch == 2 and notices == ["resuming after epoch 2"]
    assert history.train["total"] == reference.train["total"]
    for name, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[name], value, rtol=0, atol=0)
    assert reference.train["total"][-1] < reference.train["total"][0]


def test_a_cosine_rate_changes_the_steps_and_the_checkpoint_pins_the_epoch_count(grid, monkeypatch):
    """The schedule reaches the optimiser (each step's rate is the schedule's at its place in the whole run), and
    a cosine run's checkpoint does not resume a run of another length (its rates would differ)."""
    mesh, frames = _problem(grid)
    train_ids, test_ids = torch.arange(6), torch.tensor([6])
    rates = []
    monkeypatch.setattr(model.training, "set_learning_rate",
                        lambda optimizer, rate: (rates.append(rate), set_learning_rate(optimizer, rate)))
    saved = []
    fit(_model(grid), mesh, frames, train_ids, test_ids, TrainSettings(epochs=3, lr_schedule="cosine"),
        save_checkpoint=lambda state: saved.append(_stored(state)))
    steps = 3 * 2    # 6 frames in batches of 3
    assert rates == pytest.approx([learning_rate("cosine", 1e-3, i, steps) for i in range(steps)])
    notices = []
    fit(_model(grid), mesh, frames, train_ids, test_ids, TrainSettings(epochs=5, lr_schedule="cosine"),
        resume_from=saved[0], on_notice=notices.append)
    assert "starting afresh" in notices[0]


def test_input_noise_acts_in_training_steps_only(grid):
    """Noise changes the steps (other losses, other weights) but not what the trained model computes from a
    frame once training ends: evaluation is deterministic."""
    mesh, frames = _problem(grid)
    train_ids, test_ids = torch.arange(6), torch.tensor([6])
    clean, noisy = _model(grid), _model(grid)
    plain = fit(clean, mesh, frames, train_ids, test_ids, TrainSettings(epochs=2))
    jittered = fit(noisy, mesh, frames, train_ids, test_ids, TrainSettings(epochs=2, input_noise=0.5))
    assert plain.train["total"][0] != jittered.train["total"][0]
    batch = frames.store.batch(test_ids)
    torch.testing.assert_close(noisy(batch, mesh), noisy(batch, mesh), rtol=0, atol=0)
    assert not noisy.training and noisy.input_noise == 0.5


def test_stale_checkpoint_starts_afresh_and_a_damaged_one_is_an_error(grid):
    mesh, frames = _problem(grid)
    saved = []
    fit(_model(grid), mesh, frames, torch.arange(6), torch.tensor([6]), TrainSettings(epochs=1, lr=1e-2),
        save_checkpoint=lambda state: saved.append(_stored(state)))
    notices = []
    history = fit(_model(grid), mesh, frames, torch.arange(6), torch.tensor([6]), TrainSettings(epochs=1),
                  resume_from=saved[0], on_notice=notices.append)
    assert history.resumed_from_epoch == 0 and "starting afresh" in notices[0]
    damaged = {**saved[0], "model": {"no such": torch.zeros(1)}}
    with pytest.raises(CheckpointError, match="cannot be restored"):
        fit(_model(grid), mesh, frames, torch.arange(6), torch.tensor([6]), TrainSettings(epochs=1, lr=1e-2),
            resume_from=damaged)


def test_split_errors_match_numpy(grid):
    _, frames = _problem(grid)
    ids = torch.tensor([0, 2, 3, 5, 6])
    errors = split_errors(lambda inputs: 0.5 * torch.sin(7 * inputs.positions) * 0.01, frames, ids, batch_size=2,
                          weights=LossWeights(1.0, 2.0, 0.0))
    difference = (0.5 * 0.01 * np.sin(7 * frames.store.low.numpy()) - frames.targets.numpy())[ids.numpy()]
    assert np.isclose(errors["l1"], np.abs(difference).mean(), rtol=1e-5)
    # L2 over the whole split, not a mean of per-batch L2s
    assert np.isclose(errors["l2"], np.sqrt((difference ** 2).sum(-1).mean()), rtol=1e-5)
    assert np.isclose(errors["total"], errors["l1"] + 2 * errors["l2"], rtol=1e-6)


def test_no_op_of_a_training_step_reads_uninitialised_memory(grid):
    """pipeline.core.torch_setup turns off deterministic mode's NaN fill of new tensors (an extra kernel each): safe only
    while nothing reads memory it did not write. With the fill on, such a read would turn the result into NaN or
    change it; training with body-relative local inputs and all three loss terms must come out bit for bit equal."""
    vertices, faces, mesh = grid
    _, frames = _problem(grid)
    store = frames.store
    capsule_a = torch.tensor([[0.2, 0.0, 0.1], [0.5, 0.3, -0.1]]).expand(len(store), 2, 3)
    store = FrameStore(store.low, store.subdivide, torch.clamp(torch.arange(len(store)) - 1, min=0),
                       capsule_a,
                       capsule_a + 0.3, torch.tensor([0.05, 0.1]), torch.tensor([0.08, 0.02]), store.gravity, 0.1)
    frames = Frames(store, frames.targets, frames.faces)
    spec = FeatureSpec(("velocity", "body", "laplacian", "gravity"), "local", "local", "gravity")
    results = []
    was = torch.are_deterministic_algorithms_enabled(), torch.utils.deterministic.fill_uninitialized_memory
    try:
        for fill in (True, False):
            torch.use_deterministic_algorithms(True)
            torch.utils.deterministic.fill_uninitialized_memory = fill
            torch.manual_seed(0)
            model = FeatureRegressor(build_network(NetworkSpec("D8 D D8", "RC7", in_channels=spec.channels)), spec,
                                     faces, vertices, output_scale=0.01)
            history = fit(model, mesh, frames, torch.arange(6), torch.tensor([6]),
                          TrainSettings(epochs=2, weights=LossWeights(1.0, 1.0, 0.1)))
            results.append((history.batch_total, model.state_dict()))
    finally:
        torch.use_deterministic_algorithms(was[0])
        torch.utils.deterministic.fill_uninitialized_memory = was[1]
    assert results[0][0] == results[1][0] and all(np.isfinite(results[0][0]))
    for name, value in results[0][1].items():
        torch.testing.assert_close(results[1][1][name], value, rtol=0, atol=0)
