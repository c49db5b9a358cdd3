"""Which training frames an epoch visits, and in what order (settings `training.sample_share`, `sample_block`,
`sample_buffer`).

The paper samples 10 % of its 486,720 frames per epoch. A dataset of that size lives on disk (model.streaming),
where consecutive frames are one read and scattered ones one read each; so frames are drawn in blocks of
`block` consecutive positions of the training list. Blocks are drawn without replacement across epochs (a cycle:
every block once before any twice), so every frame is visited within ceil(1 / share) epochs, and none twice in an
epoch. The drawn frames are
then shuffled within each stretch of `buffer` frames of the draw (what a streaming loader holds at once), so a
batch mixes frames of several blocks.

With `block` 1 no shuffle follows the draw (single frames are in random order already) and a share of 1 draws
one `torch.randperm` of every frame per epoch: the order fit() has always used, bit for bit.

All randomness comes from the generator passed in (fit's shuffle generator, saved in the checkpoint); what
the sampler carries between epochs (the rest of the current cycle) is `state()`, a tensor for the checkpoint.
"""
from __future__ import annotations

import dataclasses

import torch


@dataclasses.dataclass(frozen=True)
class SampleSettings:
    share: float = 1.0       # of the training frames per epoch, in (0, 1]
    block: int = 1           # consecutive training frames drawn together
    buffer: int = 4096       # frames shuffled together after the draw (and read together when streaming)

    def __post_init__(self):
        if not (0 < self.share <= 1 and self.block >= 1 and self.buffer >= 1):
            raise ValueError(f"sample share must lie in (0, 1], block and buffer be >= 1; got {self}")


class Sampler:
    """Epoch orders over `n` training frames (positions 0..n-1 of the training list)."""

    def __init__(self, n: int, settings: SampleSettings = SampleSettings()):
        if n < 1:
            raise ValueError("no training frames to sample")
        self.n, self.settings = n, settings
        self.n_blocks = -(-n // settings.block)
        self.blocks_per_epoch = max(1, round(settings.share * self.n_blocks))
        self._pending = torch.zeros(0, dtype=torch.int64)     # blocks of the current cycle not drawn yet

    @property
    def frames_per_epoch(self) -> int:
        """The most frames an epoch visits (fewer by at most block - 1 when the short last block is drawn)."""
        return min(self.n, self.blocks_per_epoch * self.settings.block)

    def epoch(self, generator: torch.Generator) -> torch.Tensor:
        """The next epoch's order: positions into the training list (int64, CPU)."""
        blocks = self._draw(generator)
        block = self.settings.block
        if block == 1:
            return blocks
        frames = (blocks[:, None] * block + torch.arange(block)).reshape(-1)
        frames = frames[frames < self.n]
        buffer = self.settings.buffer
        return torch.cat([part[torch.randperm(len(part), generator=generator)]
                          for part in frames.split(buffer)])

    def _draw(self, generator: torch.Generator) -> torch.Tensor:
        """`blocks_per_epoch` blocks: the rest of the current cycle, then a new cycle's first ones (a block this
        epoch already drew goes to the end of the new cycle, so no epoch visits a frame twice)."""
        drawn, wanted = [], self.blocks_per_epoch
        while wanted:
            if not len(self._pending):
                fresh = torch.randperm(self.n_blocks, generator=generator)
                again = torch.isin(fresh, torch.cat(drawn)) if drawn else torch.zeros(len(fresh), dtype=torch.bool)
                self._pending = torch.cat([fresh[~again], fresh[again]])
            drawn.append(self._pending[:wanted])
            self._pending = self._pending[wanted:]
            wanted -= len(drawn[-1])
        return torch.cat(drawn)

    def state(self) -> torch.Tensor:
        return self._pending.clone()

    def restore(self, pending: torch.Tensor) -> None:
        pending = torch.as_tensor(pending, dtype=torch.int64)
        if pending.ndim != 1 or (len(pending) and (pending.min() < 0 or pending.max() >= self.n_blocks)):
            raise ValueError("sampler state of another dataset")
        self._pending = pending.clone()
