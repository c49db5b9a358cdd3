"""model.data_parallel's arithmetic, one process standing in for each rank: every step's frames shared out
exactly once, the weights that make the ranks' averaged loss the mean over the step's frames, the ranks read
from torchrun's environment. The ranks training together (gloo, two processes):
tests/pipeline/test_train_torchrun.py."""
from __future__ import annotations

import pytest
import torch

from model.data_parallel import Ranks, my_part, step_share, steps_of


def shares(order: torch.Tensor, batch: int, size: int) -> list[tuple[torch.Tensor, float]]:
    return [step_share(order, batch, Ranks(rank, size)) for rank in range(size)]


@pytest.mark.parametrize("frames, batch, size", [(11, 2, 2), (11, 5, 2), (12, 3, 2), (10, 3, 4), (3, 3, 4),
                                                 (1, 1, 3), (37, 4, 3)])
def test_each_step_is_the_one_process_step_shared_out_and_weighted_to_its_mean(frames, batch, size):
    order = torch.randperm(100, generator=torch.Generator().manual_seed(frames))[:frames]
    steps = steps_of(frames, batch, Ranks(0, size))
    assert steps == len(range(0, frames, batch * size))
    per_rank = shares(order, batch, size)
    values = torch.rand(100, generator=torch.Generator().manual_seed(1), dtype=torch.float64)   # a frame's loss
    for step in range(steps):
        reference = order[step * batch * size:(step + 1) * batch * size]     # the one process's step
        parts, weights = [], []
        for ids, last_weight in per_rank:
            assert (steps - 1) * batch < len(ids) <= steps * batch      # full batches, then the last
            part = ids[step * batch:(step + 1) * batch]
            weight = last_weight if step == steps - 1 else 1.0
            assert len(part) >= 1                  # every rank takes part in every step's reduction
            parts.append(part if weight else part[:0])
            weights.append(weight)
        assert sorted(torch.cat(parts).tolist()) == sorted(reference.tolist())
        # DDP averages the ranks' gradients of weight x (mean over their frames): the mean over the step's frames
        averaged = sum(w * values[p].mean() for p, w in zip(parts, weights) if w) / size
        assert averaged == pytest.approx(float(values[reference].mean()), rel=1e-12)
        sizes = [len(p) for p in parts]
        assert max(sizes) - min(sizes) <= 1 if step == steps - 1 else set(sizes) == {batch}


def test_one_rank_is_the_one_process():
    order = torch.arange(11)
    ids, weight = step_share(order, 3, Ranks())
    assert torch.equal(ids, order) and weight == 1.0
    assert torch.equal(my_part(order, Ranks()), order)


def test_the_monitored_test_frames_are_shared_out_once():
    ids = torch.arange(10)
    parts = [my_part(ids, Ranks(rank, 4)) for rank in range(4)]
    assert sorted(torch.cat(parts).tolist()) == ids.tolist() and [len(p) for p in parts] == [3, 3, 2, 2]
    assert [len(my_part(ids[:1], Ranks(rank, 2))) for rank in range(2)] == [1, 0]


def test_ranks_come_from_torchruns_environment():
    assert Ranks.from_environment({}) == Ranks(0, 1, 0) and not Ranks().parallel
    ranks = Ranks.from_environment({"WORLD_SIZE": "8", "RANK": "5", "LOCAL_RANK": "1"})
    assert (ranks.rank, ranks.size, ranks.local, ranks.main, ranks.parallel) == (5, 8, 1, False, True)
    for bad in ({"WORLD_SIZE": "2", "RANK": "2"}, {"WORLD_SIZE": "two"}, {"WORLD_SIZE": "2", "RANK": "-1"}):
        with pytest.raises(ValueError):
            Ranks.from_environment(bad)
