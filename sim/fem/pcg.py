"""Conjugate gradients preconditioned by the inverses of a block-sparse matrix's 3 x 3 diagonal blocks, for a
block-diagonal system of several worlds: each world has its own step lengths and its own stopping test, so the
worlds' solves are independent though they share every launch (warp.optim.linear's CG shares one step length
among everything and cost ~6 ms an iteration on the CPU, against ~0.1 ms here).

Vectors are (B N,) vec3d, world w's rows w N .. w N + N - 1.
"""
from __future__ import annotations

import numpy as np
import warp as wp
import warp.sparse as wps

# A world whose p^T A p or r^T z is at most this stops moving (its residual is zero or A is singular along p).
TINY = 1.0e-300


@wp.kernel
def _invert_blocks(diagonal: wp.array(dtype=wp.mat33d), out: wp.array(dtype=wp.mat33d)):
    """The inverse of each diagonal block; the identity's scaled by 1/trace where a block is singular (a node whose
    tets' projected stiffness vanishes along some direction)."""
    i = wp.tid()
    D = diagonal[i]
    trace = D[0, 0] + D[1, 1] + D[2, 2]
    if wp.abs(wp.determinant(D)) > wp.float64(1.0e-12) * trace * trace * trace:
        out[i] = wp.inverse(D)
    elif trace > wp.float64(0.0):
        out[i] = wp.identity(n=3, dtype=wp.float64) / trace
    else:
        out[i] = wp.identity(n=3, dtype=wp.float64)


@wp.kernel
def _apply_blocks(blocks: wp.array(dtype=wp.mat33d), r: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    out[i] = blocks[i] * r[i]


@wp.kernel
def _world_dot(a: wp.array(dtype=wp.vec3d), b: wp.array(dtype=wp.vec3d), n: int, out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    wp.atomic_add(out, i // n, wp.dot(a[i], b[i]))


@wp.kernel
def _update_solution(x: wp.array(dtype=wp.vec3d), r: wp.array(dtype=wp.vec3d), p: wp.array(dtype=wp.vec3d),
                     ap: wp.array(dtype=wp.vec3d), rz: wp.array(dtype=wp.float64),
                     pap: wp.array(dtype=wp.float64), n: int, indefinite: wp.array(dtype=wp.int32)):
    i = wp.tid()
    w = i // n
    alpha = wp.float64(0.0)
    if pap[w] > TINY and rz[w] > TINY:
        alpha = rz[w] / pap[w]
    elif pap[w] <= wp.float64(0.0) and rz[w] > TINY:
        indefinite[w] = 1
    x[i] = x[i] + alpha * p[i]
    r[i] = r[i] - alpha * ap[i]


@wp.kernel
def _update_direction(p: wp.array(dtype=wp.vec3d), z: wp.array(dtype=wp.vec3d), rz_new: wp.array(dtype=wp.float64),
                      rz: wp.array(dtype=wp.float64), n: int):
    i = wp.tid()
    w = i // n
    beta = wp.float64(0.0)
    if rz[w] > TINY:
        beta = rz_new[w] / rz[w]
    p[i] = z[i] + beta * p[i]


class BlockJacobiCG:
    """Solves A x = b for the worlds' block-diagonal A (a warp.sparse matrix of 3 x 3 blocks), starting from x = 0,
    until every world's residual |b - A x| is at most `tolerance` |b| of that world (checked every `check_every`
    iterations) or after `max_iterations`. A world whose A shows a direction of negative curvature stops moving
    and is reported (`indefinite`). Work arrays are made once, for `worlds` worlds of `n` nodes."""

    def __init__(self, worlds: int, n: int, device, check_every: int = 5):
        self.worlds, self.n, self.device, self.check_every = worlds, n, device, check_every
        vectors = lambda: wp.zeros(worlds * n, dtype=wp.vec3d, device=device)  # noqa: E731
        self.r, self.z, self.p, self.ap = vectors(), vectors(), vectors(), vectors()
        self.inverse = wp.zeros(worlds * n, dtype=wp.mat33d, device=device)
        scalars = lambda: wp.zeros(worlds, dtype=wp.float64, device=device)  # noqa: E731
        self.rz, self.rz_new, self.pap, self.rr = scalars(), scalars(), scalars(), scalars()
        self.indefinite = wp.zeros(worlds, dtype=wp.int32, device=device)

    def _dot(self, a: wp.array, b: wp.array, out: wp.array) -> None:
        out.zero_()
        wp.launch(_world_dot, dim=len(a), inputs=[a, b, self.n, out], device=self.device)

    def _precondition(self) -> None:
        wp.launch(_apply_blocks, dim=len(self.r), inputs=[self.inverse, self.r, self.z], device=self.device)

    def solve(self, A: wps.BsrMatrix, b: wp.array, x: wp.array, tolerance: float,
              max_iterations: int) -> tuple[int, np.ndarray]:
        """x <- the solution; returns the iterations done and which worlds' A is indefinite (B,) bool."""
        launch = lambda kernel, inputs: wp.launch(kernel, dim=len(x), inputs=inputs, device=self.device)  # noqa
        wp.launch(_invert_blocks, dim=len(x), inputs=[wps.bsr_get_diag(A), self.inverse], device=self.device)
        x.zero_()
        self.indefinite.zero_()
        wp.copy(self.r, b)
        self._dot(b, b, self.rr)
        goal = tolerance ** 2 * self.rr.numpy()
        self._precondition()
        wp.copy(self.p, self.z)
        self._dot(self.r, self.z, self.rz)
        for iteration in range(1, max_iterations + 1):
            wps.bsr_mv(A, self.p, self.ap, alpha=1.0, beta=0.0)
            self._dot(self.p, self.ap, self.pap)
            launch(_update_solution, [x, self.r, self.p, self.ap, self.rz, self.pap, self.n, self.indefinite])
            if iteration % self.check_every == 0 or iteration == max_iterations:
                self._dot(self.r, self.r, self.rr)
                indefinite = self.indefinite.numpy() == 1
                if ((self.rr.numpy() <= goal) | indefinite).all():
                    return iteration, indefinite
            self._precondition()
            self._dot(self.r, self.z, self.rz_new)
            launch(_update_direction, [self.p, self.z, self.rz_new, self.rz, self.n])
            wp.copy(self.rz, self.rz_new)
        return max_iterations, self.indefinite.numpy() == 1
