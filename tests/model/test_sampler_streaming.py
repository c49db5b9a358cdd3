"""Issue 35, item 4: S x_low computed on the device (model.features.Subdivider) against scipy; the sampler of a share
of the training frames (model.sampler); training streamed a batch at a time (model.streaming) against training
with every frame resident, bit for bit on the CPU, and resumed from a checkpoint mid-cycle of the sampler; a trained
network scored over every frame a chunk at a time (model.scoring, the evaluate stage), resident or streamed, against
the training's split errors."""
from __future__ import annotations

import dataclasses
import io

import numpy as np
import pytest
import torch

from geometry.loop_subdivision import loop_subdivide
from model.feature_regressor import FeatureRegressor, FeatureSpec
from model.features import FrameStore, Subdivider, previous_frames
from model.networks import NetworkSpec, build_network
from model.sampler import Sampler, SampleSettings
from model.streaming import FrameSource, StreamedFrames
from model.losses import LossWeights
from model.scoring import score_frames
from model.training import Frames, TrainSettings, fit, split_batch_size, split_errors
from model_meshes import build_hierarchy, grid_mesh

N_FRAMES = 40


@pytest.fixture(scope="module")
def sheet():
    """A 4 x 5 low-res grid Loop-subdivided once, 40 frames of it in two sequences (velocity and acceleration read
    the previous frames), and targets that depend on S x_low."""
    low_vertices, low_faces = grid_mesh(4, 5)
    S, faces = loop_subdivide(low_vertices, low_faces, 1)
    generator = np.random.default_rng(5)
    t = np.arange(N_FRAMES)[:, None, None]
    low = (low_vertices[None] + 0.05 * np.sin(0.3 * t + 4 * low_vertices[None, :, :1])
           + 0.01 * generator.standard_normal((N_FRAMES, *low_vertices.shape))).astype(np.float32)
    high = np.stack([S @ x for x in low.astype(np.float64)])
    targets = (0.01 * np.sin(9 * high)).astype(np.float32)
    sequence = np.repeat([0, 1], N_FRAMES // 2)
    return S, faces, low, targets, sequence, build_hierarchy(faces, S.shape[0], 7, 3)


def test_s_x_low_on_the_device_is_scipys_product_to_float32_round_off(sheet):
    S, _, low, *_ = sheet
    subdivide = Subdivider(S.indptr, S.indices, S.data)
    got = subdivide(torch.as_tensor(low)).numpy()
    expected = np.stack([S @ x for x in low.astype(np.float64)])     # what dataset.h5 stored as `input` before
    scale = np.abs(expected).max()
    np.testing.assert_allclose(got, expected, rtol=0, atol=4 * np.finfo(np.float32).eps * scale)
    np.testing.assert_allclose(got, expected.astype(np.float32), rtol=0, atol=4 * np.finfo(np.float32).eps * scale)
    # Batched or alone, a frame's S x_low is the same bits (no arithmetic across frames).
    alone = np.concatenate([subdivide(torch.as_tensor(low[k:k + 1])).numpy() for k in range(3)])
    assert np.array_equal(alone, got[:3])


def test_a_share_of_one_frame_blocks_is_the_permutation_training_always_drew():
    sampler, drawn, expected = Sampler(17), torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    for _ in range(3):
        assert torch.equal(sampler.epoch(drawn), torch.randperm(17, generator=expected))


@pytest.mark.parametrize("share, block", [(0.1, 1), (0.25, 4), (0.3, 5)])
def test_the_sampler_draws_its_share_in_whole_blocks_and_covers_every_frame_in_a_cycle(share, block):
    n = 103
    sampler = Sampler(n, SampleSettings(share, block, buffer=16))
    generator = torch.Generator().manual_seed(1)
    blocks_per_epoch = max(1, round(share * -(-n // block)))
    epochs = -(-sampler.n_blocks // blocks_per_epoch)        # one cycle: every block once
    seen = []
    for _ in range(epochs):
        order = sampler.epoch(generator).numpy()
        assert len(order) <= blocks_per_epoch * block and len(order) >= blocks_per_epoch * block - (block - 1)
        assert len(np.unique(order)) == len(order)
        # Whole blocks: every drawn frame's block drawn entirely.
        drawn_blocks = np.unique(order // block)
        whole = np.concatenate([np.arange(b * block, min((b + 1) * block, n)) for b in drawn_blocks])
        assert np.array_equal(np.sort(order), whole)
        seen.append(order)
    visits = np.bincount(np.concatenate(seen), minlength=n)
    assert visits.min() == 1 and visits.max() <= 2          # every frame in one cycle; the next cycle's first ones
    assert (visits == 2).sum() < blocks_per_epoch * block


def test_the_sampler_shuffles_within_its_buffer_and_is_deterministic_by_seed():
    settings = SampleSettings(0.5, 4, buffer=8)
    first, again, other = (Sampler(64, settings).epoch(torch.Generator().manual_seed(s)) for s in (2, 2, 3))
    assert torch.equal(first, again) and not torch.equal(first, other)
    for start in range(0, len(first), 8):     # a buffer holds two whole blocks, their frames mixed
        part = first[start:start + 8].numpy()
        assert len(np.unique(part // 4)) == 2 and not np.array_equal(part, np.sort(part))


def _frames(sheet, streamed: bool) -> Frames:
    S, faces, low, targets, sequence, _ = sheet
    previous = previous_frames(sequence)
    no_body = np.zeros((N_FRAMES, 0, 3), np.float32)
    gravity = np.tile(np.float32([0.0, -1.0, 0.0]), (N_FRAMES, 1))
    subdivide = Subdivider(S.indptr, S.indices, S.data)
    if streamed:
        source = FrameSource(lambda first, stop: (low[first:stop], targets[first:stop]), N_FRAMES, previous,
                             no_body, no_body, np.zeros(0, np.float32), np.zeros(0, np.float32), gravity, 0.1)
        return StreamedFrames.create(source, subdivide, torch.as_tensor(faces), S.shape[0], split_batch_size(3),
                                     torch.device("cpu"), window=7)
    t = torch.as_tensor
    store = FrameStore(t(low), subdivide, t(previous), t(no_body), t(no_body), torch.zeros(0), torch.zeros(0),
                       t(gravity), 0.1)
    return Frames(store, t(targets), t(faces))


def _model(sheet, frames: Frames, train_ids: torch.Tensor) -> FeatureRegressor:
    S, faces = sheet[0], sheet[1]
    torch.manual_seed(0)
    spec = FeatureSpec(("position", "velocity", "acceleration"))
    net = build_network(NetworkSpec("D8 D D8", "RC7", in_channels=spec.channels))
    model = FeatureRegressor(net, spec, faces, S @ sheet[2][0].astype(np.float64))
    model.normalise(*_normalisation(frames, train_ids))
    return model


def _normalisation(frames: Frames, train_ids: torch.Tensor):
    store, targets = frames.all_frames()
    return store, train_ids, targets


SETTINGS = TrainSettings(epochs=3, sampling=SampleSettings(0.5, 4, buffer=8), input_noise=0.1)


def test_streamed_training_equals_resident_training_bit_for_bit(sheet):
    """Normalisation (statistics and output scale read from disk), every step and the test errors: the staging
    area holds the frames of each batch and their previous ones, the loader thread reads a window at a time."""
    mesh = sheet[-1]
    test_ids = torch.tensor([5, 13, 31])
    train_ids = torch.as_tensor(np.setdiff1d(np.arange(N_FRAMES), test_ids.numpy()))
    runs = {}
    for streamed in (False, True):
        frames = _frames(sheet, streamed)
        model = _model(sheet, frames, train_ids)
        history = fit(model, mesh, frames, train_ids, test_ids, SETTINGS)
        runs[streamed] = model, history
    (resident, kept), (streamed, read) = runs[False], runs[True]
    assert kept.train == read.train and kept.test == read.test and kept.batch_total == read.batch_total
    for name, value in resident.state_dict().items():
        assert torch.equal(streamed.state_dict()[name], value), name
    assert kept.train["total"][-1] < kept.train["total"][0]


def _stored(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


@pytest.mark.parametrize("streamed", [False, True])
def test_a_run_resumed_mid_cycle_of_the_sampler_equals_the_uninterrupted_one(sheet, streamed):
    """Share 0.5: a cycle of the sampler spans two epochs, so the checkpoint after epoch 1 holds its second half."""
    mesh = sheet[-1]
    train_ids, test_ids = torch.arange(N_FRAMES - 4), torch.arange(N_FRAMES - 4, N_FRAMES)
    saved = []
    straight = _model(sheet, _frames(sheet, streamed), train_ids)
    reference = fit(straight, mesh, _frames(sheet, streamed), train_ids, test_ids, SETTINGS,
                    save_checkpoint=lambda state: saved.append(_stored(state)))
    assert len(saved[0]["sampler"]) > 0
    resumed = _model(sheet, _frames(sheet, streamed), train_ids)
    history = fit(resumed, mesh, _frames(sheet, streamed), train_ids, test_ids, SETTINGS, resume_from=saved[0],
                  on_notice=lambda notice: None)
    assert history.resumed_from_epoch == 1 and history.train["total"] == reference.train["total"]
    for name, value in straight.state_dict().items():
        assert torch.equal(resumed.state_dict()[name], value), name


def test_a_read_error_reaches_the_training_as_the_readers_exception(sheet):
    frames = _frames(sheet, True)

    def broken(first: int, stop: int):
        raise OSError(f"frames {first}-{stop} unreadable")
    frames = dataclasses.replace(frames, source=dataclasses.replace(frames.source, read=broken))
    with pytest.raises(OSError, match="unreadable"):
        list(frames.feed(torch.arange(10), 3))


def test_the_test_frames_an_epoch_scores_are_all_of_them_or_an_even_spread_of_the_most():
    from model.training import MONITORED_TEST_FRAMES, monitored_test_frames
    few = torch.arange(10, 10 + MONITORED_TEST_FRAMES)
    assert torch.equal(monitored_test_frames(few), few)
    many = torch.arange(3 * MONITORED_TEST_FRAMES + 5) * 2
    chosen = monitored_test_frames(many)
    assert len(chosen) == MONITORED_TEST_FRAMES and len(torch.unique(chosen)) == MONITORED_TEST_FRAMES
    assert chosen[0] == many[0] and chosen[-1] == many[-1] and bool(torch.isin(chosen, many).all())
    gaps = torch.diff(chosen) // 2
    assert gaps.min() >= 2 and gaps.max() <= 4                                     # evenly spread, ~3 apart


def _network(sheet, frames: Frames):
    """A network (normalised on the first 30 frames) and what model.scoring calls to predict a chunk with it."""
    model = _model(sheet, frames, torch.arange(30))
    return model, lambda ids, inputs: model(inputs, sheet[-1])


@pytest.mark.parametrize("chunk", [3, N_FRAMES])
def test_frame_scores_give_the_split_errors_of_every_split_and_the_per_frame_errors(sheet, chunk):
    """model.scoring's split figures against model.training.split_errors over the whole split (its definitions:
    positions S x_low + displacement, L2 over every frame together, Ln, the weighted total), whatever the chunk;
    they differ by the order of float32 sums alone (a frame's mean, then a mean of frames in float64): rtol 1e-5.
    The per-frame L1 and L2 of the displacement error against numpy in float64."""
    frames = _frames(sheet, streamed=False)
    model, predict = _network(sheet, frames)
    weights = LossWeights(1.0, 0.5, 0.2)
    scores = score_frames(predict, frames, N_FRAMES, chunk)
    for ids in (np.array([5, 13, 31]), np.arange(30), np.arange(N_FRAMES)):
        tensor = torch.as_tensor(ids)
        for who, expected in (("network", split_errors(lambda inputs: model(inputs, sheet[-1]), frames, tensor, 8,
                                                        weights)),
                              ("predictor", split_errors(lambda inputs: torch.zeros_like(inputs.positions), frames,
                                                          tensor, 8, weights))):
            got = scores.split(who, ids, weights)
            assert got.keys() == expected.keys()
            for term in expected:
                assert got[term] == pytest.approx(expected[term], rel=1e-5, abs=1e-12), (who, term)
    with torch.no_grad():
        displacement = model(frames.store.batch(torch.arange(N_FRAMES)), sheet[-1]).double().numpy()
    for who, error in (("network", displacement - sheet[3]), ("predictor", -sheet[3].astype(np.float64))):
        np.testing.assert_allclose(scores.per_frame[who]["l1"], np.abs(error).mean(axis=(1, 2)), rtol=1e-5)
        np.testing.assert_allclose(scores.per_frame[who]["l2"], np.sqrt(np.square(error).sum(2).mean(1)), rtol=1e-5)


def test_a_streamed_scoring_is_the_resident_one_bit_for_bit_each_chunk_handed_over_once(sheet):
    """The same chunks of the same frames, resident or read from disk into the staging area (model.streaming):
    the same predictions and scores, bit for bit on the CPU; every frame in exactly one chunk, in order."""
    runs = {}
    for streamed in (False, True):
        frames = _frames(sheet, streamed)
        _, predict = _network(sheet, frames)
        chunks = []
        scores = score_frames(predict, frames, N_FRAMES, 6,
                              lambda ids, displacement: chunks.append((ids, displacement.clone())))
        runs[streamed] = scores, chunks
    (resident, kept), (streamed, read) = runs[False], runs[True]
    assert [len(ids) for ids, _ in kept] == [6] * 6 + [4]
    assert np.array_equal(np.concatenate([ids for ids, _ in kept]), np.arange(N_FRAMES))
    for (ids, displacement), (other_ids, other) in zip(kept, read, strict=True):
        assert np.array_equal(ids, other_ids) and torch.equal(displacement, other)
    for who in ("network", "predictor"):
        assert np.array_equal(resident.terms[who], streamed.terms[who])
        for term in ("l1", "l2"):
            assert np.array_equal(resident.per_frame[who][term], streamed.per_frame[who][term])
