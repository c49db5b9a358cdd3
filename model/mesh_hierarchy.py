"""The mesh hierarchy a network runs on: per level a convolution table, and pooling/unpooling maps between levels.

Conventions (those of the operators artifact): a convolution table is (V_i, L) with vertex ids stored +1, so that
0 names the zero-padding slot and column 0 is the vertex itself; `pool[i]` (V_{i+1}, 2) lists the one or two
level-i vertices merged into each level-(i+1) vertex (both columns equal for a single one); `unpool[i]` (V_i,)
is the level-(i+1) vertex of each level-i vertex.
"""
from __future__ import annotations

import dataclasses
import hashlib
from typing import Sequence

import numpy as np
import torch


@dataclasses.dataclass(frozen=True)
class MeshHierarchy:
    """Index tables of levels 0..n (n pooling steps), as torch int64 tensors on one device."""

    conv: tuple[torch.Tensor, ...]      # n+1 tables (V_i, L), +1 ids
    pool: tuple[torch.Tensor, ...]      # n tables (V_{i+1}, 2)
    unpool: tuple[torch.Tensor, ...]    # n tables (V_i,)

    @property
    def n_levels(self) -> int:
        return len(self.conv)

    @property
    def conv_size(self) -> int:
        return int(self.conv[0].shape[1])

    @property
    def vertex_counts(self) -> list[int]:
        return [int(t.shape[0]) for t in self.conv]

    def to(self, device: torch.device | str) -> MeshHierarchy:
        move = lambda tables: tuple(t.to(device) for t in tables)  # noqa: E731
        return MeshHierarchy(move(self.conv), move(self.pool), move(self.unpool))

    def truncated(self, n_levels: int) -> MeshHierarchy:
        """The first `n_levels` levels (what a network actually uses)."""
        if not 1 <= n_levels <= self.n_levels:
            raise ValueError(f"a network needs {n_levels} mesh levels but the hierarchy has {self.n_levels}")
        return MeshHierarchy(self.conv[:n_levels], self.pool[:n_levels - 1], self.unpool[:n_levels - 1])

    def fingerprint(self) -> str:
        """SHA-256 of every table, so a trained model can recognise the operators it was trained with."""
        digest = hashlib.sha256()
        for table in (*self.conv, *self.pool, *self.unpool):
            array = table.detach().cpu().numpy().astype(np.int64)
            digest.update(np.asarray(array.shape, dtype=np.int64).tobytes())
            digest.update(array.tobytes())
        return digest.hexdigest()


def mesh_hierarchy(conv: Sequence[np.ndarray], pool: Sequence[np.ndarray],
                   unpool: Sequence[np.ndarray]) -> MeshHierarchy:
    """Validate operator tables and turn them into a `MeshHierarchy`; raises ValueError naming level and table.

    `conv` has one table per level, `pool` and `unpool` one per pooling step (len(conv) - 1).
    """
    if len(conv) == 0:
        raise ValueError("no convolution tables given")
    if len(pool) != len(conv) - 1 or len(unpool) != len(conv) - 1:
        raise ValueError(f"{len(conv)} levels need {len(conv) - 1} pool and unpool tables, "
                         f"got {len(pool)} and {len(unpool)}")
    sizes = {np.shape(t)[1] if np.ndim(t) == 2 else None for t in conv}
    if len(sizes) != 1 or None in sizes:
        raise ValueError(f"convolution tables must all be (V_i, L) with one L, got shapes "
                         f"{[np.shape(t) for t in conv]}")
    counts = [len(t) for t in conv]
    for level, table in enumerate(conv):
        _check_conv(level, np.asarray(table), counts[level])
    for level, (down, up) in enumerate(zip(pool, unpool)):
        _check_pooling(level, np.asarray(down), np.asarray(up), counts[level], counts[level + 1])
    as_tensor = lambda tables: tuple(torch.as_tensor(np.asarray(t, dtype=np.int64)) for t in tables)  # noqa: E731
    return MeshHierarchy(as_tensor(conv), as_tensor(pool), as_tensor(unpool))


def _check_conv(level: int, table: np.ndarray, n_vertices: int) -> None:
    if not np.issubdtype(table.dtype, np.integer):
        raise ValueError(f"level {level}: convolution table must hold integers, got {table.dtype}")
    if table.min() < 0 or table.max() > n_vertices:
        raise ValueError(f"level {level}: convolution table ids must lie in [0, {n_vertices}] (+1 ids, 0 = padding)"
                         f", found {table.min()}..{table.max()}")
    if not np.array_equal(table[:, 0], np.arange(1, n_vertices + 1)):
        raise ValueError(f"level {level}: column 0 of the convolution table must be each vertex itself (id + 1)")


def _check_pooling(level: int, pool: np.ndarray, unpool: np.ndarray, n_fine: int, n_coarse: int) -> None:
    if pool.shape != (n_coarse, 2) or unpool.shape != (n_fine,):
        raise ValueError(f"level {level}: pool must be ({n_coarse}, 2) and unpool ({n_fine},), "
                         f"got {pool.shape} and {unpool.shape}")
    if pool.min() < 0 or pool.max() >= n_fine or unpool.min() < 0 or unpool.max() >= n_coarse:
        raise ValueError(f"level {level}: pool ids must lie in [0, {n_fine}) and unpool ids in [0, {n_coarse})")
    # Pooling and unpooling must describe the same edge collapses: every fine vertex merged into a coarse one
    # unpools back to it, and every fine vertex is merged somewhere.
    coarse = np.arange(n_coarse)
    if not (np.array_equal(unpool[pool[:, 0]], coarse) and np.array_equal(unpool[pool[:, 1]], coarse)):
        raise ValueError(f"level {level}: pool and unpool tables disagree (a pooled vertex unpools elsewhere)")
    if len(np.unique(pool)) != n_fine:
        raise ValueError(f"level {level}: pool table leaves some level-{level} vertices out")
