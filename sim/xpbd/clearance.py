"""Shapes held clear of the mannequin's capsules outside the solver's step (host code and its kernels): the high-res
run's harmonic targets are taken from S x_low moved clear of the body, the way the solver's substeps end
(`sim.xpbd.body_contact.keep_outside`, capsules taking turns FINAL_PASSES times)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True})

from sim.xpbd.body_contact import FINAL_PASSES, capsule_shape, keep_outside


@wp.func
def outside_frame_capsules(x: wp.vec3, f: int, ends: wp.array3d(dtype=wp.vec3), radii: wp.array2d(dtype=float),
                           thickness: float) -> wp.vec3:
    """x to `thickness` outside frame f's capsules (ends (F, P, 2), radii (P, 2)): the nearest-point projection of
    finish_substep, capsules taking turns FINAL_PASSES times (the crease where two overlap)."""
    for _ in range(FINAL_PASSES):
        total = float(0.0)
        for c in range(ends.shape[1]):
            a = ends[f, c, 0]
            b = ends[f, c, 1]
            ra = radii[c, 0]
            rb = radii[c, 1]
            if wp.length(x - 0.5 * (a + b)) > 0.5 * wp.length(b - a) + wp.max(ra, rb) + thickness:
                continue
            x, moved = keep_outside(x, x, capsule_shape(a, b, ra, rb), thickness)
            total = total + moved
        if total == 0.0:
            break
    return x


@wp.kernel
def move_outside_capsules(points: wp.array2d(dtype=wp.vec3), ends: wp.array3d(dtype=wp.vec3),
                          radii: wp.array2d(dtype=float), thickness: float):
    """Points (F, N) moved outside frame f's capsules in place (outside_frame_capsules)."""
    f, i = wp.tid()
    points[f, i] = outside_frame_capsules(points[f, i], f, ends, radii, thickness)


@wp.kernel
def subdivided_outside_capsules(row_start: wp.array(dtype=int), columns: wp.array(dtype=int),
                                weights: wp.array(dtype=float), coarse: wp.array2d(dtype=wp.vec3),
                                ends: wp.array3d(dtype=wp.vec3), radii: wp.array2d(dtype=float), thickness: float,
                                offsets: wp.array2d(dtype=wp.vec3), moved: wp.array(dtype=int)):
    """Row i of S (CSR) times frame f's coarse points (F, V_low), moved outside frame f's capsules: the offset of
    the move in offsets (F, V), and moved[i] = 1 where some frame moved vertex i (moved starts at 0)."""
    f, i = wp.tid()
    x = wp.vec3(0.0)
    for k in range(row_start[i], row_start[i + 1]):
        x += weights[k] * coarse[f, columns[k]]
    cleared = outside_frame_capsules(x, f, ends, radii, thickness)
    offsets[f, i] = cleared - x
    if wp.length_sq(cleared - x) > 0.0:
        moved[i] = 1            # every writer writes 1: no race on the value


@wp.kernel
def gather_vertices(points: wp.array2d(dtype=wp.vec3), ids: wp.array(dtype=int), out: wp.array2d(dtype=wp.vec3)):
    """out[f, j] = points[f, ids[j]]."""
    f, j = wp.tid()
    out[f, j] = points[f, ids[j]]


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
    wp.launch(move_outside_capsules, dim=points.shape[:2], device=device,
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
        wp.launch(subdivided_outside_capsules, dim=(frames, vertices), device=device,
                  inputs=[self._rows, self._columns, self._weights, wp.array(coarse, dtype=wp.vec3, device=device),
                          wp.array(np.ascontiguousarray(capsules, dtype=np.float32), dtype=wp.vec3, device=device),
                          self._radii, self.thickness, offsets, moved])
        ids = np.flatnonzero(moved.numpy())
        if len(ids) == 0:
            return ids, np.zeros((frames, 0, 3), dtype=np.float32)
        out = wp.empty((frames, len(ids)), dtype=wp.vec3, device=device)
        wp.launch(gather_vertices, dim=out.shape, device=device,
                  inputs=[offsets, wp.array(ids.astype(np.int32), dtype=int, device=device), out])
        return ids, out.numpy()
