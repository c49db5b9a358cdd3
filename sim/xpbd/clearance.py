"""Shapes held clear of the mannequin's capsules outside the solver's step."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

from sim.xpbd import collision


def _check_body(frames: int, capsules: np.ndarray, radii: np.ndarray) -> None:
    if frames != capsules.shape[0] or capsules.shape[2:] != (2, 3) or radii.shape != (capsules.shape[1], 2):
        raise ValueError(f"{frames} frames of points, capsules {capsules.shape} and radii {radii.shape} do not match")


def outside_body(points: np.ndarray, capsules: np.ndarray, radii: np.ndarray, thickness: float,
                 device: str) -> np.ndarray:
    """Points (F, N, 3) moved to `thickness` outside frame f's capsules (F, P, 2, 3) with radii (P, 2), by the
    projection the solver ends each substep with; points already that far out stay where they are."""
    points = np.asarray(points, dtype=np.float32)
    _check_body(points.shape[0], capsules, radii)
    if points.size == 0 or capsules.shape[1] == 0:
        return points.copy()
    x = wp.array(points, dtype=wp.vec3, device=device)
    ends = wp.array(np.ascontiguousarray(capsules, dtype=np.float32), dtype=wp.vec3, device=device)
    wp.launch(collision.move_outside_capsules, dim=points.shape[:2], device=device,
              inputs=[x, ends, wp.array(np.ascontiguousarray(radii, dtype=np.float32), dtype=float, device=device),
                      float(thickness)])
    return x.numpy()


class SubdividedOutsideBody:
    """S x_coarse per frame moved clear of the body as `outside_body` moves it, computed on the device from the
    coarse frames: only those go to the device and only the moved vertices' offsets come back. A high-res batch
    job's harmonic targets need this per sequence; through `outside_body` each paper-pants sequence cost a (F, V, 3)
    round trip (~45 ms over pageable memory on the H100, under the batch's Warp lock) plus S x_coarse on the host
    (~0.1 s), ~4 s of a 64-sequence job's setup (2026-11-24)."""

    def __init__(self, S: sp.csr_matrix, radii: np.ndarray, thickness: float, device: str):
        S = sp.csr_matrix(S)
        self.shape, self.device, self.thickness = S.shape, device, float(thickness)
        self._rows = wp.array(S.indptr.astype(np.int32), dtype=int, device=device)
        self._columns = wp.array(S.indices.astype(np.int32), dtype=int, device=device)
        self._weights = wp.array(S.data.astype(np.float32), dtype=float, device=device)
        self._radii_host = np.asarray(radii)
        self._radii = wp.array(np.ascontiguousarray(radii, dtype=np.float32), dtype=float, device=device)

    def __call__(self, coarse: np.ndarray, capsules: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coarse points (F, V_coarse, 3) and frame f's capsules (F, P, 2, 3) -> the ids (M,) of the vertices of
        S x_coarse that some frame moved, and their offsets (F, M, 3) float32 from S x_coarse (0 in a frame that
        left the vertex where it was)."""
        coarse = np.ascontiguousarray(coarse, dtype=np.float32)
        if coarse.ndim != 3 or coarse.shape[1:] != (self.shape[1], 3):
            raise ValueError(f"coarse points {coarse.shape} do not match S {self.shape}")
        _check_body(coarse.shape[0], capsules, self._radii_host)
        frames, vertices = coarse.shape[0], self.shape[0]
        if frames == 0 or capsules.shape[1] == 0:
            return np.zeros(0, dtype=np.int64), np.zeros((frames, 0, 3), dtype=np.float32)
        device = self.device
        offsets = wp.empty((frames, vertices), dtype=wp.vec3, device=device)
        moved = wp.zeros(vertices, dtype=int, device=device)
        wp.launch(collision.subdivided_outside_capsules, dim=(frames, vertices), device=device,
                  inputs=[self._rows, self._columns, self._weights, wp.array(coarse, dtype=wp.vec3, device=device),
                          wp.array(np.ascontiguousarray(capsules, dtype=np.float32), dtype=wp.vec3, device=device),
                          self._radii, self.thickness, offsets, moved])
        ids = np.flatnonzero(moved.numpy())
        if len(ids) == 0:
            return ids, np.zeros((frames, 0, 3), dtype=np.float32)
        out = wp.empty((frames, len(ids)), dtype=wp.vec3, device=device)
        wp.launch(collision.gather_vertices, dim=out.shape, device=device,
                  inputs=[offsets, wp.array(ids.astype(np.int32), dtype=int, device=device), out])
        return ids, out.numpy()
