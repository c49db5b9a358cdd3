"""The harmonic targets of a high-res cloth run and its residual: B^T M products per frame, in float64 with numpy's
BLAS on the host (pipeline.solvers.xpbd's high-res run; bench/batched_sim.py makes its targets the same way)."""
from __future__ import annotations

import numpy as np


def per_frame_product(A, x: np.ndarray) -> np.ndarray:
    """A @ x[f] for every frame f of x (F, V, C), A (K, V) dense or sparse: one matrix product over all frames at
    once (F x C columns). np.einsum would loop in C without BLAS: minutes for a paper-size batch."""
    n_frames, n_vertices, channels = x.shape
    columns = np.ascontiguousarray(x.transpose(1, 0, 2)).reshape(n_vertices, n_frames * channels)
    return np.asarray(A @ columns).reshape(A.shape[0], n_frames, channels).transpose(1, 0, 2)


class BasisProducts:
    """B^T M x per frame (F, K, 3) of the frames x (F, V, 3) of one garment's high-res runs (`high`), and
    (B^T M S) x_low of its low-res ones (`low`), in float64 with numpy's BLAS. On the host, not the device: a
    job's products run on its threads while the device steps (the residual) or take ~0.1 s a paper-pants sequence
    (the targets), and doing them on a GPU with torch cost the job torch's import (4.3 s on the H100's host)."""

    def __init__(self, mass_basis_t: np.ndarray, S):
        self._high = np.ascontiguousarray(mass_basis_t, dtype=np.float64)
        self._low = np.ascontiguousarray((S.T @ self._high.T).T)      # B^T M S (K, V_low): the targets', factored

    def high(self, x: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
        """B^T M x per frame; with `columns`, over those high-res vertices only (x then (F, len(columns), 3))."""
        A = self._high if columns is None else self._high[:, columns]
        return per_frame_product(A, x.astype(np.float64, copy=False))

    def low(self, x_low: np.ndarray) -> np.ndarray:
        """(B^T M S) x_low per frame: B^T M of S x_low without forming S x_low."""
        return per_frame_product(self._low, x_low.astype(np.float64, copy=False))


def harmonic_targets_of(x_low: np.ndarray, products: BasisProducts,
                        moved: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """B^T M x per frame (F, K, 3) of x = S x_low moved clear of the body: `moved` holds the ids of the vertices
    of S x_low the body moves and their offsets (F, M, 3), as sim.xpbd.clearance.SubdividedOutsideBody gives them.

    As (B^T M S) x_low plus B^T M of the moved vertices' offsets: the same sum as B^T M x over all V high-res
    vertices, for a product with the V_low coarse ones (1/16) and one with the moved vertices. The whole (K, V)
    product per frame was most of the high-res stage's setup for a 64-world batch (single-threaded BLAS, 2026-11-24).
    """
    targets = products.low(x_low)
    if moved is not None and len(moved[0]):
        targets += products.high(moved[1], moved[0])
    return targets
