"""Training on several processes (`torchrun --nproc_per_node=N`) with DistributedDataParallel: NCCL between
GPUs, gloo between CPU processes.

N ranks at a batch of B frames each train as one process at a batch of N x B: every rank draws the same epoch
order from the same seeded generator (model.sampler), and of every step's N x B frames rank r takes the r-th B.
DDP averages the ranks' gradients; each rank's loss is a mean over its frames, so with equal shares the average
is the gradient of the mean over the step's frames, which is what the one process computes (exactly for the L1
and normal terms; the L2 term is a square root of a mean, so there the ranks' roots are averaged). An epoch's
shorter last step is shared as evenly as it goes, each rank's loss weighted by N x its share of the step's
frames, so that the average is again the mean over the step's frames; a rank left without a frame runs one with
weight 0, as every rank must take part in each step's gradient reduction. What differs from the one process is
only the order of the float additions (the reduction), a rounding-level difference that Adam's steps compound
(each gradient divided by its own running RMS): tests/pipeline/test_train_torchrun.py states the tolerance, after 3
epochs the weights within 2e-5 and the losses within 1e-6 relative of the one process's.

Each rank holds the dataset on its device (or, streaming, reads from disk only its own frames of each step),
scores its share of the monitored test frames, and the ranks' sums are combined: the history every rank keeps
is the one process's. Only rank 0 writes the checkpoint and the outputs.
"""
from __future__ import annotations

import contextlib
import dataclasses
import inspect
import os
from typing import Iterator, Mapping

import torch
import torch.distributed as dist
from torch import nn


@dataclasses.dataclass(frozen=True)
class Ranks:
    """This process's place among the training's processes: rank `rank` of `size`, `local` on its machine."""

    rank: int = 0
    size: int = 1
    local: int = 0

    @property
    def main(self) -> bool:
        """Rank 0: the one that writes checkpoints and outputs and shows progress."""
        return self.rank == 0

    @property
    def parallel(self) -> bool:
        return self.size > 1

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] = os.environ) -> "Ranks":
        """The ranks torchrun (or any launcher of torch.distributed's env:// convention) describes: WORLD_SIZE,
        RANK, LOCAL_RANK; one process of one where WORLD_SIZE is absent."""
        if "WORLD_SIZE" not in environ:
            return cls()
        try:
            size, rank = int(environ["WORLD_SIZE"]), int(environ.get("RANK", "0"))
            local = int(environ.get("LOCAL_RANK", str(rank)))
        except ValueError:
            raise ValueError("WORLD_SIZE, RANK and LOCAL_RANK must be whole numbers") from None
        if not 0 <= rank < size or local < 0:
            raise ValueError(f"RANK {rank} of WORLD_SIZE {size}: a rank must lie in 0 .. WORLD_SIZE - 1")
        return cls(rank, size, local)


SINGLE = Ranks()
# Buffers never synchronised at a forward (DistributedDataParallel's keyword: `forward_sync_buffers` since torch 2.13,
# which deprecates `broadcast_buffers`; the CUDA builds of torch 2.11 know only the latter).
NO_BUFFER_SYNC = ({"forward_sync_buffers": False}
                  if "forward_sync_buffers" in inspect.signature(nn.parallel.DistributedDataParallel).parameters
                  else {"broadcast_buffers": False})


@contextlib.contextmanager
def process_group(ranks: Ranks, device: torch.device, graphed: bool = False) -> Iterator[None]:
    """Within: this process in the training's process group (MASTER_ADDR/MASTER_PORT from the launcher), NCCL
    on CUDA, gloo on the CPU; nothing for one process. `graphed`: steps replayed as CUDA graphs, whose capture
    NCCL's asynchronous error handling (a watchdog querying the stream's events) would break, as torch's CUDA
    graph notes say: it is turned off for this process before the group starts."""
    if not ranks.parallel:
        yield
        return
    if device.type == "cuda":
        if graphed:
            os.environ["TORCH_NCCL_ASYNC_ERROR_HANDLING"] = "0"
        torch.cuda.set_device(device)
    dist.init_process_group("nccl" if device.type == "cuda" else "gloo", rank=ranks.rank, world_size=ranks.size,
                            device_id=device if device.type == "cuda" else None)
    try:
        yield
    finally:
        dist.destroy_process_group()


def step_share(order: torch.Tensor, batch_size: int, ranks: Ranks) -> tuple[torch.Tensor, float]:
    """This rank's frames of an epoch's `order`, in its steps' order: of every full step (ranks.size x
    `batch_size` frames) the rank's `batch_size`; of a shorter last step an even share (sizes differ by one at
    most), or, where none is left for it, the epoch's first frame with weight 0. Returns them and the weight of
    the rank's last step (1 where the epoch ends on a full step)."""
    step = batch_size * ranks.size
    full = len(order) // step * step
    mine = order[:full].reshape(-1, ranks.size, batch_size)[:, ranks.rank].reshape(-1)
    rest = order[full:]
    if not len(rest):
        return mine, 1.0
    part = torch.tensor_split(rest, ranks.size)[ranks.rank]
    if not len(part):
        return torch.cat([mine, order[:1]]), 0.0
    return torch.cat([mine, part]), ranks.size * len(part) / len(rest)


def steps_of(frames: int, batch_size: int, ranks: Ranks) -> int:
    """Optimiser steps of an epoch of `frames` frames at `batch_size` a rank."""
    return -(-frames // (batch_size * ranks.size))


def my_part(ids: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """The rank's part of a split scored after each epoch: every size-th frame from its rank on."""
    return ids[ranks.rank::ranks.size]


def sum_over_ranks(values: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """The element-wise sum of `values` over the ranks (values itself for one process)."""
    if ranks.parallel:
        values = values.clone()
        dist.all_reduce(values)
    return values


def gather_over_ranks(value: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """Every rank's `value` (equal shapes), stacked in rank order, on every rank."""
    parts = [None] * ranks.size
    dist.all_gather_object(parts, value.cpu())
    return torch.stack(parts)


def combined_errors(errors: Mapping[str, float] | None, count: int, ranks: Ranks, weights,
                    device: torch.device) -> dict[str, float]:
    """A split's errors over every rank's part (model.training.split_errors of `count` frames each, None for a
    rank without a frame): L1 and normal are means, combined weighted by the parts' frames; L2 is a root mean
    square, combined as one; the total again weights the terms (model.losses). Reduced on `device`, the
    training's (NCCL reduces CUDA tensors only)."""
    own = [0.0, 0.0, 0.0] if errors is None else [errors["l1"], errors["l2"] ** 2, errors["normal"]]
    sums = sum_over_ranks(torch.tensor([*(count * value for value in own), count], dtype=torch.float64,
                                       device=device), ranks)
    l1, l2sq, normal = (sums[:3] / sums[3]).tolist()
    combined = {"l1": l1, "l2": l2sq ** 0.5, "normal": normal}
    combined["total"] = weights.l1 * combined["l1"] + weights.l2 * combined["l2"] + weights.normal * combined["normal"]
    return combined


@contextlib.contextmanager
def distributed(model: nn.Module, ranks: Ranks) -> Iterator[None]:
    """`model.net` (the network every regressor trains) run through DistributedDataParallel for the duration.

    The wrapper is put in the model's instance dict, where attribute lookup finds it before the registered
    submodules: the regressor's forward calls it (DDP's gradient hooks fire), while `parameters()`,
    `state_dict()` and `.to()` still see the plain network, so checkpoints and model.pt keep their keys and the
    optimiser updates the same tensors. Buffers are not broadcast at each forward (the normalisation is fixed and
    equal on every rank; a broadcast would be a collective in the per-epoch scoring, where the ranks' parts may
    take different numbers of batches). On CUDA the wrapper is built on a side stream, as a step replayed as a
    CUDA graph requires (torch.cuda.graphs)."""
    if not ranks.parallel:
        yield
        return
    net = model.net
    device = next(net.parameters()).device
    side = torch.cuda.Stream(device) if device.type == "cuda" else None
    with torch.cuda.stream(side) if side is not None else contextlib.nullcontext():
        wrapped = nn.parallel.DistributedDataParallel(net, device_ids=[device] if side is not None else None,
                                                      **NO_BUFFER_SYNC)
    if side is not None:
        torch.cuda.current_stream(device).wait_stream(side)
    model.__dict__["net"] = wrapped
    try:
        yield
    finally:
        del model.__dict__["net"]
