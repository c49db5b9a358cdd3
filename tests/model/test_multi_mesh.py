"""One network on several meshes (model/multi_mesh.py): a mixed batch's loss and gradient against each mesh's own
computed separately, the samples' coverage of every garment's frames, the shared normalisation against each
garment's statistics, one garment's training against the one-mesh training, resuming, and an unknown mesh."""
from __future__ import annotations

import copy
import io

import numpy as np
import pytest
import torch

from model.feature_regressor import FeatureRegressor, FeatureSpec, store_statistics
from model.features import FrameStore
from model.losses import LossWeights, total_loss
from model.multi_mesh import Garment, MultiMeshFrames, MultiMeshRegressor, UnknownMeshError, spread
from model.networks import NetworkSpec, build_network
from model.training import Frames, TrainSettings, fit
from model_meshes import build_hierarchy, grid_mesh, identity_subdivider

SPEC = FeatureSpec(("position", "laplacian"))
WEIGHTS = LossWeights(1.0, 0.5, 0.1)


def _garment(name: str, rows: int, cols: int, n_frames: int, n_train: int, seed: int) -> tuple[Garment, tuple]:
    """A flat grid waving in `n_frames` random frames, its first `n_train` frames trained on, the rest tested."""
    vertices, faces = grid_mesh(rows, cols)
    generator = torch.Generator().manual_seed(seed)
    base = torch.as_tensor(vertices, dtype=torch.float32)
    inputs = base + 0.05 * torch.randn(n_frames, *base.shape, generator=generator)
    targets = 0.01 * torch.sin(7 * inputs) + 0.002 * seed
    no_body = torch.zeros(n_frames, 0, 3)
    store = FrameStore(inputs, identity_subdivider(inputs.shape[1]), torch.arange(n_frames), no_body, no_body,
                       torch.zeros(0), torch.zeros(0),
                       torch.tensor([[0.0, -1.0, 0.0]]).expand(n_frames, 3), 0.1)
    frames = Frames(store, targets, torch.as_tensor(faces))
    mesh = build_hierarchy(faces, len(vertices), 7, 3)
    ids = torch.arange(n_frames)
    return Garment(name, frames, mesh, ids[:n_train], ids[n_train:]), (faces, vertices)


@pytest.fixture
def garments():
    """Two meshes of different vertex counts and connectivity, with different numbers of frames per split."""
    a, mesh_a = _garment("a", 6, 7, 9, 6, seed=1)
    b, mesh_b = _garment("b", 5, 4, 7, 4, seed=2)
    return [a, b], {"a": mesh_a, "b": mesh_b}


def _network():
    torch.manual_seed(0)
    return build_network(NetworkSpec("D8 D D8", "RC7", in_channels=SPEC.channels))


def test_a_mixed_batch_loss_and_gradient_are_the_mean_of_each_garments_own(garments):
    parts, meshes = garments
    model = MultiMeshRegressor(_network(), SPEC, meshes)
    model.normalise(parts)
    problem = MultiMeshFrames(parts)
    samples = torch.tensor([0, 3, 5])
    loss, terms = problem.batch_loss(model, problem.meshes, samples, WEIGHTS)
    loss.backward()
    mixed = {name: p.grad.clone() for name, p in model.net.named_parameters()}

    # Each garment alone, on a copy of its regressor, with the frames worked out here: b has 4 training frames
    # for 6 samples, so sample k takes its frame floor(4 k / 6).
    expected_frames = {"a": torch.tensor([0, 3, 5]), "b": torch.tensor([0, 2, 3])}
    alone, gradients = [], []
    for garment in parts:
        regressor = copy.deepcopy(model.part(garment.name))
        ids = expected_frames[garment.name]
        inputs = garment.frames.store.batch(ids)
        own, own_terms = total_loss(inputs.positions + regressor(inputs, garment.mesh),
                                    inputs.positions + garment.frames.targets[ids], garment.frames.faces, WEIGHTS)
        own.backward()
        alone.append((own, own_terms))
        gradients.append({name: p.grad for name, p in regressor.net.named_parameters()})
    torch.testing.assert_close(loss, (alone[0][0] + alone[1][0]) / 2, rtol=1e-6, atol=0)
    for name in ("l1", "l2", "normal"):
        torch.testing.assert_close(terms[name], (alone[0][1][name] + alone[1][1][name]) / 2, rtol=1e-6, atol=0)
    for name, grad in mixed.items():
        torch.testing.assert_close(grad, (gradients[0][name] + gradients[1][name]) / 2, rtol=1e-5, atol=1e-9)


def test_samples_show_every_frame_of_every_garment_and_keep_the_splits_apart(garments):
    parts, _ = garments
    problem = MultiMeshFrames(parts)
    assert len(problem.train_samples) == 6 and len(problem.test_samples) == 3     # the most frames per split
    for garment, train, test in zip(parts, problem.frame_ids(problem.train_samples),
                                    problem.frame_ids(problem.test_samples)):
        assert set(train.tolist()) == set(garment.train.tolist())
        assert set(test.tolist()) == set(garment.test.tolist())
        counts = np.bincount(train.numpy())[garment.train.numpy()]
        assert counts.min() >= 1 and counts.max() - counts.min() <= 1        # repeats evenly spread
    assert spread(torch.arange(3), 3).tolist() == [0, 1, 2]
    with pytest.raises(ValueError):
        spread(torch.arange(4), 3)


def test_the_normalisation_is_the_garments_statistics_averaged(garments):
    parts, meshes = garments
    model = MultiMeshRegressor(_network(), SPEC, meshes)
    model.normalise(parts)
    statistics = [store_statistics(model.part(g.name).features, g.frames.store, g.train) for g in parts]
    offset = (statistics[0][0].double() + statistics[1][0].double()) / 2
    scale = ((statistics[0][1].double() ** 2 + statistics[1][1].double() ** 2) / 2).sqrt()
    output = np.sqrt(np.mean([float(g.frames.targets[g.train].double().square().mean()) for g in parts]))
    for part in model.parts.values():
        torch.testing.assert_close(part.input_offset, offset.float())
        torch.testing.assert_close(part.input_scale, scale.float())
        assert part.output_scale.item() == pytest.approx(output, rel=1e-6)
    # With one garment: that garment's own normalisation, exactly.
    alone = MultiMeshRegressor(_network(), SPEC, {"a": meshes["a"]})
    alone.normalise(parts[:1])
    own = FeatureRegressor(_network(), SPEC, *meshes["a"])
    own.normalise(parts[0].frames.store, parts[0].train, parts[0].frames.targets)
    for name in ("input_offset", "input_scale", "output_scale"):
        assert torch.equal(getattr(alone.part("a"), name), getattr(own, name)), name


def test_one_garment_trains_exactly_as_the_one_mesh_training(garments):
    parts, meshes = garments
    garment = parts[0]
    single = FeatureRegressor(_network(), SPEC, *meshes["a"])
    single.normalise(garment.frames.store, garment.train, garment.frames.targets)
    fit(single, garment.mesh, garment.frames, garment.train, garment.test, TrainSettings(epochs=2, batch_size=2))
    multi = MultiMeshRegressor(_network(), SPEC, {"a": meshes["a"]})
    multi.normalise([garment])
    problem = MultiMeshFrames([garment])
    fit(multi, problem.meshes, problem, problem.train_samples, problem.test_samples,
        TrainSettings(epochs=2, batch_size=2))
    for name, value in single.state_dict().items():
        assert torch.equal(multi.part("a").state_dict()[name], value), name


def _stored(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def test_a_resumed_training_ends_as_an_uninterrupted_one_and_checkpoints_hold_the_weights_once(garments):
    parts, meshes = garments
    problem = MultiMeshFrames(parts)

    def run(epochs, **kwargs):
        model = MultiMeshRegressor(_network(), SPEC, meshes)
        model.normalise(parts)
        fit(model, problem.meshes, problem, problem.train_samples, problem.test_samples,
            TrainSettings(epochs=epochs, batch_size=2), **kwargs)
        return model

    saved = []
    run(1, save_checkpoint=lambda state: saved.append(_stored(state)))
    assert all(key.startswith("net.") for key in saved[0]["model"])
    resumed, straight = run(2, resume_from=saved[0], on_notice=lambda notice: None), run(2)
    for name, value in straight.state_dict().items():
        assert torch.equal(resumed.state_dict()[name], value), name
    assert not torch.equal(straight.state_dict()["net.convs.0.weight"], _network().state_dict()["convs.0.weight"])


def test_every_part_runs_the_one_network_and_moves_with_it(garments):
    _, meshes = garments
    model = MultiMeshRegressor(_network(), SPEC, meshes)
    assert all(part.net is model.net for part in model.parts.values())
    assert sum(p.numel() for p in model.parameters()) == model.net.parameter_count()
    model.to(torch.float64).eval()
    for part in model.parts.values():
        assert part.input_offset.dtype == part.features.rest.dtype == torch.float64 and not part.training
    assert model.train().part("b").training


def test_a_mesh_it_was_not_built_for_is_refused_by_name(garments):
    _, meshes = garments
    model = MultiMeshRegressor(_network(), SPEC, meshes)
    with pytest.raises(UnknownMeshError, match="trained on a, b; not on 'c'"):
        model.part("c")
    with pytest.raises(ValueError):
        MultiMeshRegressor(_network(), SPEC, {})
