"""One optimiser step of the training loop, run eagerly or replayed as one CUDA graph.

A training step of the mesh CNN at batch 3 is launch-bound on a GPU: a few thousand small kernels whose launch
costs the host more than the GPU spends running them (29-35 ms a step for the paper-profile pants on an H100,
docs/performance.md). Captured once and replayed, the whole step (input features, forward, loss, backward, Adam)
is one launch. Replay runs the same kernels on the same addresses, so it computes what the eager step computes;
only the batch's frame ids change, copied into the graph's input buffer before each replay.
"""
from __future__ import annotations

from typing import Callable, Mapping, Protocol

import torch

from model.mesh_hierarchy import MeshHierarchy

LOSS_TERMS = ("l1", "l2", "normal")   # the terms a Problem's batch_loss returns beside the total
WARMUP_STEPS = 3                      # eager steps on a side stream before capture (lazy initialisations)

Step = Callable[[torch.Tensor], torch.Tensor]   # frame ids (B,) -> (total, l1, l2, normal) of that batch, 0-d each


class BatchLoss(Protocol):
    """What a step needs of a learning problem: the loss of a batch of sample ids and its terms (LOSS_TERMS)."""

    def batch_loss(self, model, mesh, ids: torch.Tensor, weights) -> tuple[torch.Tensor, dict[str, torch.Tensor]]: ...


def adam(model: torch.nn.Module, lr: float, graphed: bool) -> torch.optim.Adam:
    """The paper's Adam (betas 0.9/0.999, eps 1e-8). On CUDA one fused kernel updates every parameter (the
    per-tensor loop launches several kernels a tensor); a step replayed as a graph keeps its step counts on the
    device (`capturable`)."""
    parameters = list(model.parameters())
    fused = bool(parameters) and all(p.is_cuda for p in parameters)
    return torch.optim.Adam(parameters, lr=lr, betas=(0.9, 0.999), eps=1e-8, fused=fused or None,
                            capturable=graphed)


def eager_step(model: torch.nn.Module, mesh: MeshHierarchy | Mapping[str, MeshHierarchy], problem: BatchLoss,
               optimizer: torch.optim.Optimizer, weights) -> Step:
    """Loss of the batch, backward, optimiser step; returns the loss terms, detached, on the device."""
    def step(ids: torch.Tensor) -> torch.Tensor:
        loss, terms = problem.batch_loss(model, mesh, ids, weights)
        # Zeroed in place rather than dropped: a captured step must find the same gradient tensors at every
        # replay (and 0 + g is g, so the eager arithmetic is unchanged).
        optimizer.zero_grad(set_to_none=False)
        loss.backward()
        optimizer.step()
        return torch.stack([loss.detach(), *(terms[name].detach() for name in LOSS_TERMS)])
    return step


class GraphedStep:
    """`step` for batches of `batch_size` frame ids on one CUDA device, replayed as a graph after WARMUP_STEPS
    eager steps (run on a side stream, as capture requires); a batch of another size (an epoch's last) runs
    eagerly. Every call is a real training step, the warm-up ones included. The optimiser must be capturable."""

    def __init__(self, step: Step, batch_size: int, device: torch.device):
        if torch.device(device).type != "cuda":
            raise ValueError(f"a CUDA graph needs a CUDA device, not {device}")
        self._step = step
        self._ids = torch.zeros(batch_size, dtype=torch.int64, device=device)
        self._graph: torch.cuda.CUDAGraph | None = None
        self._values: torch.Tensor | None = None
        self._warm = 0

    def __call__(self, ids: torch.Tensor) -> torch.Tensor:
        if len(ids) != len(self._ids):
            return self._step(ids)
        if self._graph is None and self._warm < WARMUP_STEPS:
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
