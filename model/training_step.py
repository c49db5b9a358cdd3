"""One optimiser step of the training loop, run eagerly or replayed as one CUDA graph.

A training step of the mesh CNN at batch 3 is launch-bound on a GPU: a few thousand small kernels whose launch
costs the host more than the GPU spends running them (29-35 ms a step for the paper-profile pants on an H100,
docs/performance.md). Captured once and replayed, the whole step (input features, forward, loss, backward, Adam)
is one launch. Replay runs the same kernels on the same addresses, so it computes what the eager step computes;
only the batch's frame ids change, copied into the graph's input buffer before each replay.
"""
from __future__ import annotations

import math
from typing import Callable, Mapping, Protocol

import torch

from model.mesh_hierarchy import MeshHierarchy

LOSS_TERMS = ("l1", "l2", "normal")   # the terms a Problem's batch_loss returns beside the total
WARMUP_STEPS = 3                      # eager steps on a side stream before capture (lazy initialisations)
# DistributedDataParallel's own: its reducer settles its buckets over the first iterations, and torch's CUDA-graph
# notes ask for at least 11 eager DDP iterations before a whole step with its gradient reduction is captured.
DDP_WARMUP_STEPS = 11

# frame ids (B,) and the weight of their loss in the gradient -> (total, l1, l2, normal) of that batch, 0-d each
Step = Callable[[torch.Tensor, float], torch.Tensor]
LR_SCHEDULES = ("constant", "cosine")
COSINE_FLOOR = 0.01    # a cosine schedule ends at 1 % of the base rate, not 0: the last steps still move


class BatchLoss(Protocol):
    """What a step needs of a learning problem: the loss of a batch of sample ids and its terms (LOSS_TERMS)."""

    def batch_loss(self, model, mesh, ids: torch.Tensor, weights) -> tuple[torch.Tensor, dict[str, torch.Tensor]]: ...


def adam(model: torch.nn.Module, lr: float, graphed: bool, scheduled: bool = False) -> torch.optim.Adam:
    """The paper's Adam (betas 0.9/0.999, eps 1e-8). On CUDA one fused kernel updates every parameter (the
    per-tensor loop launches several kernels a tensor); a step replayed as a graph keeps its step counts on the
    device (`capturable`), and a scheduled rate too: a float would be baked into the graph at capture, a tensor
    on the device is read at every replay (`set_learning_rate` writes it in place)."""
    parameters = list(model.parameters())
    fused = bool(parameters) and all(p.is_cuda for p in parameters)
    rate = torch.tensor(lr, device=parameters[0].device) if graphed and scheduled and parameters else lr
    return torch.optim.Adam(parameters, lr=rate, betas=(0.9, 0.999), eps=1e-8, fused=fused or None,
                            capturable=graphed)


def learning_rate(schedule: str, lr: float, step: int, total_steps: int) -> float:
    """The rate of optimiser step `step` (0-based) of `total_steps`: `lr` throughout (constant, the paper's), or
    half a cosine from `lr` at the first step to COSINE_FLOOR x `lr` at the last (cosine)."""
    if schedule == "constant":
        return lr
    if schedule != "cosine":
        raise ValueError(f"unknown learning-rate schedule '{schedule}'; choose one of {', '.join(LR_SCHEDULES)}")
    progress = min(step / max(total_steps - 1, 1), 1.0)
    return lr * (COSINE_FLOOR + (1 - COSINE_FLOOR) * 0.5 * (1 + math.cos(math.pi * progress)))


def set_learning_rate(optimizer: torch.optim.Optimizer, rate: float) -> None:
    """Every parameter group's rate; a tensor rate (a graphed step's) is written in place, where the graph reads
    it."""
    for group in optimizer.param_groups:
        if isinstance(group["lr"], torch.Tensor):
            group["lr"].fill_(rate)
        else:
            group["lr"] = rate


def eager_step(model: torch.nn.Module, mesh: MeshHierarchy | Mapping[str, MeshHierarchy], problem: BatchLoss,
               optimizer: torch.optim.Optimizer, weights) -> Step:
    """Loss of the batch, backward of `weight` x the loss, optimiser step; returns the loss terms (unweighted),
    detached, on the device. The weight is a rank's share of a shorter last step (model.data_parallel), 1
    otherwise."""
    def step(ids: torch.Tensor, weight: float = 1.0) -> torch.Tensor:
        loss, terms = problem.batch_loss(model, mesh, ids, weights)
        # Zeroed in place rather than dropped: a captured step must find the same gradient tensors at every
        # replay (and 0 + g is g, so the eager arithmetic is unchanged).
        optimizer.zero_grad(set_to_none=False)
        (loss if weight == 1.0 else loss * weight).backward()
        optimizer.step()
        return torch.stack([loss.detach(), *(terms[name].detach() for name in LOSS_TERMS)])
    return step


class GraphedStep:
    """`step` for batches of `batch_size` frame ids on one CUDA device, replayed as a graph after WARMUP_STEPS
    eager steps (run on a side stream, as capture requires; `warmup` of them, DDP_WARMUP_STEPS for a network run
    through DistributedDataParallel); a batch of another size or weight (an epoch's last) runs eagerly. Every call
    is a real training step, the warm-up ones included. The optimiser must be capturable."""

    def __init__(self, step: Step, batch_size: int, device: torch.device, warmup: int = WARMUP_STEPS):
        if torch.device(device).type != "cuda":
            raise ValueError(f"a CUDA graph needs a CUDA device, not {device}")
        self._step = step
        self._ids = torch.zeros(batch_size, dtype=torch.int64, device=device)
        self._graph: torch.cuda.CUDAGraph | None = None
        self._values: torch.Tensor | None = None
        self._warm, self._warmup = 0, warmup

    def __call__(self, ids: torch.Tensor, weight: float = 1.0) -> torch.Tensor:
        if len(ids) != len(self._ids) or weight != 1.0:
            return self._step(ids, weight)
        if self._graph is None and self._warm < self._warmup:
            self._warm += 1
            side = torch.cuda.Stream(device=self._ids.device)
            side.wait_stream(torch.cuda.current_stream(self._ids.device))
            with torch.cuda.stream(side):
                values = self._step(ids)
            torch.cuda.current_stream(self._ids.device).wait_stream(side)
            return values
        self._ids.copy_(ids)
        if self._graph is None:
            # Capturing records the kernels without running them: the replay below does this batch's step.
            self._graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(self._graph):
                self._values = self._step(self._ids)
        self._graph.replay()
        return self._values.clone()      # the next replay overwrites the graph's output
