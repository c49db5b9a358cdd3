"""The paper's building blocks (sections 3.1-3.3) on channels-last features x of shape (B, V, C).

Every operator is a gather over a precomputed table (`model.mesh_hierarchy`), so a network runs unchanged on any
mesh whose tables it is given.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

LEAKY_SLOPE = 0.01      # paper section 4
NORM_EPS = 1e-5         # paper section 4


def mesh_conv(x: torch.Tensor, table: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """Mesh convolution: gather the L table entries of every vertex, then one dense matmul.

    x (B, V, C_in); table (V, L) with +1 ids (0 = a zero row standing for the boundary dummy vertex);
    weight (L * C_in, C_out), ordered slot-major; bias (C_out,). Returns (B, V, C_out).
    """
    batch, n_vertices = x.shape[0], table.shape[0]
    padded = F.pad(x, (0, 0, 1, 0))                    # row 0 is the zero-padding slot
    gathered = padded.index_select(1, table.reshape(-1)).reshape(batch, n_vertices, -1)
    return torch.matmul(gathered, weight) + bias


def avg_pool(x: torch.Tensor, pool: torch.Tensor) -> torch.Tensor:
    """Average of the one or two fine vertices merged into each coarse vertex; pool (V_coarse, 2)."""
    return 0.5 * (x.index_select(1, pool[:, 0]) + x.index_select(1, pool[:, 1]))


def max_pool(x: torch.Tensor, pool: torch.Tensor) -> torch.Tensor:
    """Componentwise max of the one or two fine vertices merged into each coarse vertex."""
    return torch.maximum(x.index_select(1, pool[:, 0]), x.index_select(1, pool[:, 1]))


POOLING = {"avg": avg_pool, "max": max_pool}


def unpool(x: torch.Tensor, unpool_index: torch.Tensor) -> torch.Tensor:
    """Nearest-neighbour unpooling: each fine vertex copies the coarse vertex it was merged into; (V_fine,)."""
    return x.index_select(1, unpool_index)


def instance_norm(x: torch.Tensor, eps: float = NORM_EPS) -> torch.Tensor:
    """Instance normalisation over the vertices of each sample and channel, without affine parameters.

    No affine: the paper's Table 3 parameter counts leave no room for them (docs/architecture.md, section
    "Network architecture grammar").
    """
    mean = x.mean(dim=1, keepdim=True)
    var = x.var(dim=1, unbiased=False, keepdim=True)
    return (x - mean) * torch.rsqrt(var + eps)


def leaky_relu(x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu(x, LEAKY_SLOPE)


class MeshConv(nn.Module):
    """A learnable mesh convolution: L * C_in * C_out weights + C_out biases."""

    def __init__(self, in_channels: int, out_channels: int, size: int):
        super().__init__()
        self.in_channels, self.out_channels, self.size = in_channels, out_channels, size
        self.weight = nn.Parameter(torch.empty(size * in_channels, out_channels))
        self.bias = nn.Parameter(torch.empty(out_channels))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # nn.Linear's default over the gathered fan-in L * C_in.
        bound = 1.0 / math.sqrt(self.size * self.in_channels)
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
        if table.shape[1] != self.size:
            raise ValueError(f"convolution built for L={self.size} got a table with L={table.shape[1]}")
        return mesh_conv(x, table, self.weight, self.bias)

    def extra_repr(self) -> str:
        return f"{self.in_channels}, {self.out_channels}, L={self.size}"
