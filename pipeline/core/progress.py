"""The training stages' progress bar: one tqdm bar over every optimiser step of a run, which through Snakemake's
`| tee` is also the job's log."""
from __future__ import annotations

from typing import Callable

import torch
from tqdm import tqdm


def training_bar(desc: str, epochs: int, steps_per_epoch: int, quiet: bool) -> tqdm:
    # A second between updates keeps the log short.
    return tqdm(total=epochs * steps_per_epoch, desc=desc, unit="batch", disable=quiet, mininterval=1.0)


def batch_reporter(bar: tqdm, epochs: int, steps_per_epoch: int) -> Callable[[int, torch.Tensor], None]:
    """`fit`'s on_batch for `bar`: counts steps (a resumed run starts past its checkpointed epochs) and shows the
    latest loss only when the bar redraws, so that the host waits for the GPU once a second, not every step."""
    def on_batch(epoch: int, loss: torch.Tensor) -> None:
        if bar.n == 0:
            bar.update(epoch * steps_per_epoch)
        if bar.update():
            bar.set_postfix_str(f"epoch {epoch + 1}/{epochs} loss {float(loss):.3e}", refresh=False)
    return on_batch
