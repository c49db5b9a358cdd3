"""Warp kernels of the XPBD cloth solver (Macklin, Müller & Chentanez 2016, "XPBD").

The solver is launch-bound on small meshes (~25 µs a launch on CPU, ~2 µs a graph node on an H100), so every
kernel does as much as it can per launch:
- one `predict_positions` per substep: gravity, damping, inertial prediction and kinematic pins together;
- one `solve_distance_constraints` per iteration: a vertex-centric Jacobi sweep over *all* distance-type
  constraints (stretch with compression allowance, cross-edge bending), reading x_in and writing x_out, so there
  are no atomics and no separate "apply deltas" pass;
- one `update_velocities` per substep, which also flags NaN/blow-up per substep for the host.
The harmonic-constraint projection of the high-res run adds three launches per iteration (partial reduction,
finalisation, application) because B^T M x is a reduction over all vertices. The per-vertex work of the first
three is in wp.funcs, which `sim.xpbd.collision` calls to fuse contacts into the same launches.
"""
from __future__ import annotations

import warp as wp

wp.config.quiet = True


@wp.func
def predict_vertex(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    pin_slot: wp.array(dtype=int),
    pin_target_start: wp.array(dtype=wp.vec3),
    pin_target_end: wp.array(dtype=wp.vec3),
    pin_fraction: float,
    gravity: wp.vec3,
    h: float,
    damping_factor: float,
    x_prev: wp.array(dtype=wp.vec3),
) -> wp.vec3:
    """Symplectic-Euler prediction x* = x + h (v + h g) e^{-k h}; pinned vertices jump to their target at the
    end of the substep (linear interpolation of the frame's start and end targets). Stores x in x_prev and the
    predicted velocity in v; returns x*."""
    xi = x[i]
    x_prev[i] = xi
    slot = pin_slot[i]
    if slot >= 0:
        return wp.lerp(pin_target_start[slot], pin_target_end[slot], pin_fraction)
    if inv_mass[i] > 0.0:
        vi = (v[i] + gravity * h) * damping_factor
        v[i] = vi
        return xi + vi * h
    return xi


@wp.kernel
def predict_positions(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    pin_slot: wp.array(dtype=int),
    pin_target_start: wp.array(dtype=wp.vec3),
    pin_target_end: wp.array(dtype=wp.vec3),
    pin_fraction: float,
    gravity: wp.vec3,
    h: float,
    damping_factor: float,
    x_prev: wp.array(dtype=wp.vec3),
):
    """The prediction of every vertex (see predict_vertex)."""
    i = wp.tid()
    x[i] = predict_vertex(i, x, v, inv_mass, pin_slot, pin_target_start, pin_target_end, pin_fraction, gravity, h,
                          damping_factor, x_prev)


@wp.func
def distance_correction(
    i: int,
    xi: wp.vec3,
    x_in: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    offsets: wp.array(dtype=int),
    neighbor: wp.array(dtype=int),
    constraint: wp.array(dtype=int),
    rest_min: wp.array(dtype=float),
    rest_max: wp.array(dtype=float),
    alpha_tilde: wp.array(dtype=float),
    scale: wp.array(dtype=float),
    lambda_in: wp.array(dtype=float),
    lambda_carry: float,
    lambda_out: wp.array(dtype=float),
) -> wp.vec3:
    """One Jacobi XPBD iteration over distance constraints rest_min <= |x_i - x_j| <= rest_max (XPBD eq. 18):
    the correction of vertex i (at xi = x_in[i]).

    Stretch constraints have rest_min = allowance * L, rest_max = L (compression down to 75 % is free, which lets
    wrinkles form); bending links across an edge have rest_min = rest_max. Each vertex gathers the corrections of
    its incident constraints; a constraint's Lagrange update is scaled by `scale` = relaxation / max(n_i, n_j)
    (symmetric, so momentum is conserved and both endpoints agree on lambda). The endpoint with the lower index
    owns the constraint's lambda and writes it, so no two threads write the same slot. An inequality constraint
    inside its range is inactive and its multiplier is released (lambda = 0). `lambda_carry` is 0 on a substep's
    first iteration, which resets the multipliers without a separate launch.
    """
    wi = inv_mass[i]
    dx = wp.vec3(0.0)
    for a in range(offsets[i], offsets[i + 1]):
        j = neighbor[a]
        c = constraint[a]
        d = xi - x_in[j]
        dist = wp.length(d)
        err = dist - wp.clamp(dist, rest_min[c], rest_max[c])
        w_sum = wi + inv_mass[j]
        lam = lambda_in[c] * lambda_carry
        lam_new = float(0.0)
        if err != 0.0 and w_sum > 0.0 and dist > 1.0e-12:
            alpha = alpha_tilde[c]
            d_lambda = scale[c] * (-err - alpha * lam) / (w_sum + alpha)
            dx = dx + (wi * d_lambda / dist) * d
            lam_new = lam + d_lambda
        if i < j:
            lambda_out[c] = lam_new
    return dx


@wp.kernel
def solve_distance_constraints(
    x_in: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    offsets: wp.array(dtype=int),
    neighbor: wp.array(dtype=int),
    constraint: wp.array(dtype=int),
    rest_min: wp.array(dtype=float),
    rest_max: wp.array(dtype=float),
    alpha_tilde: wp.array(dtype=float),
    scale: wp.array(dtype=float),
    lambda_in: wp.array(dtype=float),
    lambda_carry: float,
    lambda_out: wp.array(dtype=float),
    x_out: wp.array(dtype=wp.vec3),
):
    """One Jacobi sweep over the distance constraints, reading x_in and writing x_out (see distance_correction)."""
    i = wp.tid()
    xi = x_in[i]
    x_out[i] = xi + distance_correction(i, xi, x_in, inv_mass, offsets, neighbor, constraint, rest_min, rest_max,
                                        alpha_tilde, scale, lambda_in, lambda_carry, lambda_out)


@wp.func
def store_state(
    i: int,
    xi: wp.vec3,
    x_prev: wp.array(dtype=wp.vec3),
    inv_h: float,
    max_speed: float,
    substep: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    flags: wp.array(dtype=int),
):
    """x = xi, v = (xi - x_prev) / h; flags the substep if the position is not finite or the speed exceeds
    `max_speed` (the host turns the flag into an error)."""
    vi = (xi - x_prev[i]) * inv_h
    x[i] = xi
    v[i] = vi
    speed = wp.length(vi)
    if not (speed <= max_speed):  # also true for NaN
        flags[substep] = 1


@wp.kernel
def update_velocities(
    x_solved: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    inv_h: float,
    max_speed: float,
    substep: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    flags: wp.array(dtype=int),
):
    """Copies the solved positions into the state buffer and derives velocities (see store_state)."""
    i = wp.tid()
    store_state(i, x_solved[i], x_prev, inv_h, max_speed, substep, x, v, flags)


@wp.kernel
def harmonic_partial_sums(
    x: wp.array(dtype=wp.vec3),
    mass_basis: wp.array2d(dtype=float),
    rows_per_chunk: int,
    partial: wp.array2d(dtype=wp.vec3),
):
    """partial[c, k] = sum over the rows i of chunk c of (M B)[i, k] x_i: the first half of the reduction
    B^T M x. Threads with consecutive k read consecutive entries of row i, so loads coalesce on GPU."""
    c, k = wp.tid()
    n = mass_basis.shape[0]
    start = c * rows_per_chunk
    end = wp.min(start + rows_per_chunk, n)
    acc = wp.vec3(0.0)
    for i in range(start, end):
        acc = acc + mass_basis[i, k] * x[i]
    partial[c, k] = acc


@wp.kernel
def harmonic_residual(
    partial: wp.array2d(dtype=wp.vec3),
    target_start: wp.array(dtype=wp.vec3),
    target_end: wp.array(dtype=wp.vec3),
    target_fraction: float,
    residual: wp.array(dtype=wp.vec3),
):
    """r_k = (B^T M x)_k - (B^T M S x_low)_k, the low-res side interpolated linearly within the frame."""
    k = wp.tid()
    acc = wp.vec3(0.0)
    for c in range(partial.shape[0]):
        acc = acc + partial[c, k]
    residual[k] = acc - wp.lerp(target_start[k], target_end[k], target_fraction)


@wp.kernel
def harmonic_project(
    residual: wp.array(dtype=wp.vec3),
    correction_basis_t: wp.array2d(dtype=float),
    x: wp.array(dtype=wp.vec3),
):
    """x_i -= sum_k A[i, k] r_k with A = P_free B (B^T M P_free B)^{-1}: the M-orthogonal projection onto
    B^T M (x - S x_low) = 0 that leaves pinned vertices (zero rows of A) where they are. A is stored transposed
    (K, V) so that consecutive vertices read consecutive entries."""
    i = wp.tid()
    acc = wp.vec3(0.0)
    for k in range(residual.shape[0]):
        acc = acc + correction_basis_t[k, i] * residual[k]
    x[i] = x[i] - acc
