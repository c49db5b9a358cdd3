"""model.autoregressive: a network fed its own previous output. The rollout equals running each sequence frame
after frame by hand (zero at a sequence's first frame); training's inputs carry the network's own output at each
previous frame made from the truth before it; frames out of time order are refused; the store's truth reaches
the statistics' batches, shifted by a frame."""
import dataclasses

import numpy as np
import pytest
import torch

from model.autoregressive import pushforward_inputs, rollout, steps_into_sequence
from model.features import FrameStore, previous_frames
from model_meshes import identity_subdivider

# Three sequences of 4, 1 and 3 frames; 2 vertices; frame f's positions are f + vertex / 10.
SEQUENCE = np.array([0, 0, 0, 0, 1, 2, 2, 2])


def _store(displacements: bool) -> FrameStore:
    n = len(SEQUENCE)
    positions = torch.arange(n, dtype=torch.float64)[:, None, None] + torch.tensor([0.0, 0.1])[None, :, None]
    positions = positions.expand(n, 2, 3).contiguous()
    capsules = torch.zeros(n, 1, 3, dtype=torch.float64)
    truth = torch.sin(positions * 3.0) if displacements else None
    return FrameStore(positions, identity_subdivider(2), torch.as_tensor(previous_frames(SEQUENCE)), capsules,
                      capsules, torch.ones(1), torch.ones(1), torch.zeros(n, 3, dtype=torch.float64), 0.1, truth)


def _toy(inputs) -> torch.Tensor:
    """A displacement that depends on the frame and, contractively, on the previous output."""
    return 0.01 * inputs.positions + 0.5 * inputs.previous_output


def test_steps_count_from_each_sequences_first_frame_and_out_of_order_frames_are_refused():
    assert steps_into_sequence(previous_frames(SEQUENCE)).tolist() == [0, 1, 2, 3, 0, 0, 1, 2]
    with pytest.raises(ValueError, match="not in time order"):
        steps_into_sequence(np.array([0, 2, 1]))


@pytest.mark.parametrize("batch_size", [1, 2, 8])
def test_the_rollout_is_each_sequence_run_by_hand(batch_size):
    store = _store(displacements=True)          # the truth it holds must not leak into the rollout
    got = rollout(_toy, store, batch_size)
    expected = torch.zeros_like(got)
    for frame in range(len(SEQUENCE)):
        before = int(store.previous[frame])
        fed = torch.zeros(1, 2, 3, dtype=torch.float64) if before == frame else expected[before][None]
        batch = dataclasses.replace(store.batch(torch.tensor([frame])), previous_output=fed)
        expected[frame] = _toy(batch)[0]
    torch.testing.assert_close(got, expected, rtol=0, atol=0)


def test_training_inputs_carry_the_networks_own_output_at_the_previous_frame():
    store = _store(displacements=True)
    ids = torch.tensor([0, 2, 3, 4, 6])
    inputs = pushforward_inputs(_toy, store, ids)
    truth = store.displacements
    for k, frame in enumerate(ids.tolist()):
        before = int(store.previous[frame])
        if before == frame:
            assert not inputs.previous_output[k].any()                  # a sequence's first frame
            continue
        earlier = int(store.previous[before])
        fed = torch.zeros(2, 3, dtype=torch.float64) if earlier == before else truth[earlier]
        torch.testing.assert_close(inputs.previous_output[k], 0.01 * store.low[before] + 0.5 * fed)


def test_a_store_with_the_truth_gives_it_a_frame_late_and_one_without_gives_none():
    with_truth, without = _store(displacements=True), _store(displacements=False)
    batch = with_truth.batch(torch.tensor([0, 1, 3, 5]))
    expected = torch.stack([torch.zeros(2, 3, dtype=torch.float64), with_truth.displacements[0],
                            with_truth.displacements[2], torch.zeros(2, 3, dtype=torch.float64)])
    torch.testing.assert_close(batch.previous_output, expected, rtol=0, atol=0)
    assert without.batch(torch.tensor([1])).previous_output is None
