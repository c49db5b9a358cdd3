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
three is in wp.funcs, which the contact kernels (`sim.xpbd.body_contact`, `sim.xpbd.contact_sweep`) call to
fuse contacts into the same launches.

The kernels take their arrays in structs grouped by what they describe (the substep, the pins, the distance
constraints, one Jacobi sweep's buffers, the harmonic projection), so that the collision kernels, which replace
the first three, take the same groups plus their own.

Batches: a solver may step B independent copies ("worlds") of one cloth together, each with its own pins, body
and harmonic targets. The worlds' vertices are stored one after the other (vertex i belongs to world
i // world_vertices), so every per-vertex kernel runs unchanged over all of them in one launch; only what a
vertex shares with others of its world (capsules, harmonic modes, contact triangles, the blow-up flags) is found
through its world index.
"""
from __future__ import annotations

import warp as wp

from sim.xpbd.fetch import fetch

wp.config.quiet = True

# CUDA: approximate division and square root (--use_fast_math: ~2 ulp instead of IEEE rounding, denormals
# flushed to zero). The Jacobi sweeps are bound by their IEEE div/sqrt sequences: fast math cut a batched
# frame by a quarter on an H100 (docs/performance.md). No transcendental function is used here, and
# comparisons with NaN stay IEEE, so the blow-up flags still fire. The CPU build ignores the option.
wp.set_module_options({"fast_math": True})


@wp.struct
class Substep:
    """The vertices and integration constants of one substep, and where the substep lies in the frame."""
    x: wp.array(dtype=wp.vec3)       # positions: at the substep start, then the prediction, then the result
    v: wp.array(dtype=wp.vec3)       # velocities
    x_prev: wp.array(dtype=wp.vec3)  # positions at the substep start
    inv_mass: wp.array(dtype=float)  # 0 for pinned vertices
    gravity: wp.vec3
    h: float                         # substep length
    inv_h: float
    damping_factor: float            # e^{-damping h}
    max_speed: float                 # a vertex faster than this flags the substep
    f0: float                        # fraction of the frame at the substep start
    f1: float                        # at its end
    index: int                       # the substep's number in the frame, its slot in `flags`
    world_vertices: int              # vertices per world: vertex i is in world i // world_vertices
    flags: wp.array2d(dtype=int)     # (B, substeps + 1): per world one flag per substep (blow-up), then one for
                                     # overflowing self-contact lists


@wp.struct
class PinDrive:
    """Kinematic pins: vertex i with slot[i] >= 0 follows target slot[i], interpolated linearly within the frame."""
    slot: wp.array(dtype=int)        # (B V,) -1 for a free vertex
    start: wp.array(dtype=wp.vec3)   # (B P,) targets at the start of the frame, world by world
    end: wp.array(dtype=wp.vec3)     # (B P,) at its end


@wp.struct
class DistanceConstraints:
    """Constraints rest_min[c] <= |x_i - x_j| <= rest_max[c], listed per vertex (CSR) for a Jacobi gather. One
    world's: every world has the same mesh and pins, so its vertices find theirs by their id within the world (a
    batch reads the same small tables, which stay in cache, instead of B copies that streamed from memory). An
    entry's two ids and a constraint's four parameters are packed, so each is one load."""
    offsets: wp.array(dtype=int)     # (V + 1,) vertex i's entries are offsets[i] .. offsets[i + 1] - 1
    entries: wp.array(dtype=wp.vec2i)  # per entry: the other endpoint (within the world), and the constraint id
                                     # c, or -1 - c where it has compliance (a multiplier to read: its load
                                     # need not wait for the constraint's parameters)
    params: wp.array(dtype=wp.vec4)  # (C,) rest_min, rest_max, alpha_tilde = compliance / h^2, and scale =
                                     # relaxation / max(n_i, n_j) (see distance_correction)
    inv_mass: wp.array(dtype=float)  # (V,) the inverse masses of one world (the same in every world)


@wp.struct
class JacobiSweep:
    """The buffers of one Jacobi iteration: it reads x_in and lambda_in and writes x_out and lambda_out (the next
    iteration swaps them), so no thread reads what another writes."""
    x_in: wp.array(dtype=wp.vec3)
    x_out: wp.array(dtype=wp.vec3)
    lambda_in: wp.array(dtype=float)   # (B C,) world w's multipliers are w C .. w C + C - 1
    lambda_out: wp.array(dtype=float)
    lambda_carry: float              # 0 on a substep's first iteration: resets the multipliers without a launch
    lambda_per_entry: int            # 1: a multiplier per entry of the vertices' lists, (B E,), each endpoint
                                     # keeping its own (see distance_correction); 0: one per constraint, (B C,)


@wp.struct
class HarmonicProjection:
    """The hard constraint B^T M (x - S x_low) = 0 on the device, with its reduction buffers. The bases are one
    world's (every world has the same mesh and pins); residuals and targets are per world."""
    mass_basis: wp.array2d(dtype=float)          # (V, K) M B
    correction_basis_t: wp.array2d(dtype=float)  # (K, V) A^T, A = P_free B (B^T M P_free B)^{-1}
    rows_per_chunk: int
    partial: wp.array3d(dtype=wp.vec3)           # (B, V / rows_per_chunk, K) partial sums of B^T M x
    residual: wp.array2d(dtype=wp.vec3)          # (B, K)
    target_start: wp.array2d(dtype=wp.vec3)      # (B, K) B^T M S x_low at the start of the frame
    target_end: wp.array2d(dtype=wp.vec3)        # (B, K) at its end


# A sweep may spread each vertex's constraints and contacts over `lanes` adjacent threads (CUDA: 1, 2, 4, 8 or 16;
# the CPU runs 1): one cloth alone is latency-bound (~14.5k threads, a few warps per SM, each thread walking its
# lists of dependent loads), and lanes shorten every thread's walk. The lanes' partial sums meet in a butterfly of
# warp shuffles, so every lane ends with the same bits (a + b = b + a in floating point); with one lane the sum is
# the thread's own, in the order it always had. The mask names only the group's lanes: other groups of the warp
# may be elsewhere in their loops, and a group is never split (lanes divide 32 and the launch is n * lanes wide).
_LANE_GROUP = """
    const unsigned int first = (threadIdx.x & 31u) & ~(unsigned int)(lanes - 1);
    const unsigned int group = (0xffffffffu >> (32 - lanes)) << first;
"""
_LANE_SUM = """
#if defined(__CUDA_ARCH__)""" + _LANE_GROUP + """
    for (int m = 1; m < lanes; m <<= 1)
        value += __shfl_xor_sync(group, value, m);
#endif
    return value;
"""
# A vector's components in one butterfly (one network of shuffles a step): the three shuffles of a step are
# independent, so they overlap where three sums one after the other would wait on each (each sum's arithmetic is
# the scalar's, so the bits are the same).
_LANE_SUM_VEC3 = """
#if defined(__CUDA_ARCH__)""" + _LANE_GROUP + """
    for (int m = 1; m < lanes; m <<= 1) {
        const float x = __shfl_xor_sync(group, value[0], m);
        const float y = __shfl_xor_sync(group, value[1], m);
        const float z = __shfl_xor_sync(group, value[2], m);
        value[0] += x;
        value[1] += y;
        value[2] += z;
    }
#endif
    return value;
"""
_LANE_FIRST_VEC3 = """
#if defined(__CUDA_ARCH__)""" + _LANE_GROUP + """
    return wp::vec3(__shfl_sync(group, value[0], first, 32), __shfl_sync(group, value[1], first, 32),
                    __shfl_sync(group, value[2], first, 32));
#endif
    return value;
"""


@wp.func_native(_LANE_SUM)
def lane_count(value: int, lanes: int) -> int: ...


@wp.func
def lane_of(tid: int, lanes: int):
    """The item (vertex, mode) thread tid works on and its lane there, in a launch of `lanes` threads an item."""
    item = tid // lanes
    return item, tid - item * lanes


@wp.func_native(_LANE_SUM_VEC3)
def lane_sum_vec3(value: wp.vec3, lanes: int) -> wp.vec3: ...


@wp.func_native(_LANE_FIRST_VEC3)
def lane_first_vec3(value: wp.vec3, lanes: int) -> wp.vec3:
    """The vector of the group's first lane, in every lane."""
    ...


@wp.func
def predict_vertex(i: int, sub: Substep, pins: PinDrive) -> wp.vec3:
    """Symplectic-Euler prediction x* = x + h (v + h g) e^{-k h}; pinned vertices jump to their target at the
    end of the substep (linear interpolation of the frame's start and end targets). Stores x in x_prev and the
    predicted velocity in v; returns x*."""
    xi = sub.x[i]
    sub.x_prev[i] = xi
    slot = pins.slot[i]
    if slot >= 0:
        return wp.lerp(pins.start[slot], pins.end[slot], sub.f1)
    if sub.inv_mass[i] > 0.0:
        vi = (sub.v[i] + sub.gravity * sub.h) * sub.damping_factor
        sub.v[i] = vi
        return xi + vi * sub.h
    return xi


@wp.kernel
def predict_positions(sub: Substep, pins: PinDrive):
    """The prediction of every vertex (see predict_vertex)."""
    i = wp.tid()
    sub.x[i] = predict_vertex(i, sub, pins)


@wp.func
def distance_correction(i: int, world: int, xi: wp.vec3, sub: Substep, constraints: DistanceConstraints,
                        sweep: JacobiSweep, lane: int, lanes: int) -> wp.vec3:
    """One Jacobi XPBD iteration over distance constraints rest_min <= |x_i - x_j| <= rest_max (XPBD eq. 18):
    the correction of vertex i (at xi = x_in[i]).

    Stretch constraints have rest_min = allowance * L, rest_max = L (compression down to 75 % is free, which lets
    wrinkles form); bending links across an edge have rest_min = rest_max. Each vertex gathers the corrections of
    its incident constraints; a constraint's Lagrange update is scaled by `scale` = relaxation / max(n_i, n_j)
    (symmetric, so momentum is conserved and both endpoints agree on lambda). The endpoint with the lower index
    owns the constraint's lambda and writes it, so no two threads write the same slot. An inequality constraint
    inside its range is inactive and its multiplier is released (lambda = 0). A constraint without compliance
    (alpha = 0: stretch, by default) needs no multiplier, its update being the same whatever lambda is, so its
    multiplier is neither read nor written (memory traffic, not arithmetic, bounds a batched sweep).
    `lambda_carry` is 0 on a substep's first iteration, which resets the multipliers without a separate launch.
    With `lambda_per_entry` each endpoint keeps the constraint's multiplier in its own entry instead: both compute
    the same update from the same inputs (|x_i - x_j| = |x_j - x_i| and w_i + w_j = w_j + w_i exactly), so the
    two copies stay equal bit for bit and no thread reads what another wrote (the block frame's clusters, where
    another block's global writes are seen only after a cluster barrier).
    This lane's share: entries lane, lane + lanes, ... of the vertex's list (lane_sum_vec3 adds the shares up).
    `world` is vertex i's, i // world_vertices: the caller's, who knows it or shares the division (~35
    instructions on a GPU, on every sweep's critical path) with other uses.
    """
    first = world * sub.world_vertices        # world's first vertex
    per_entry = sweep.lambda_per_entry != 0
    multipliers = world * constraints.params.shape[0]
    if per_entry:
        multipliers = world * constraints.entries.shape[0]
    own = i - first
    wi = fetch(constraints.inv_mass, own)
    dx = wp.vec3(0.0)
    # Two entries a turn, the second read whether or not it exists (an existing entry's, the list's last), so
    # that their chains of loads overlap: a GPU thread issues in order, and one entry's loads would wait for the
    # last entry's arithmetic. The terms add in the list's order, as one a turn would.
    a = fetch(constraints.offsets, own) + lane
    end = fetch(constraints.offsets, own + 1)
    while a < end:
        b = a + lanes
        term_a, on_a, slot_a, lam_a = entry_correction(a, i, first, wi, xi, multipliers, per_entry, constraints,
                                                       sweep)
        term_b, on_b, slot_b, lam_b = entry_correction(wp.min(b, end - 1), i, first, wi, xi, multipliers, per_entry,
                                                       constraints, sweep)
        dx = take_entry(dx, term_a, on_a, slot_a, lam_a, sweep)
        if b < end:
            dx = take_entry(dx, term_b, on_b, slot_b, lam_b, sweep)
        a = b + lanes
    return dx


@wp.func
def take_entry(dx: wp.vec3, term: wp.vec3, active: bool, slot: int, lam: float, sweep: JacobiSweep) -> wp.vec3:
    """An entry_correction taken: its term added to dx where active, its multiplier stored where it has a slot."""
    if slot >= 0:
        sweep.lambda_out[slot] = lam
    if active:
        return dx + term
    return dx


@wp.func
def entry_correction(a: int, i: int, first: int, wi: float, xi: wp.vec3, multipliers: int, per_entry: bool,
                     constraints: DistanceConstraints, sweep: JacobiSweep):
    """Entry a of vertex i's list (distance_correction): the vertex's correction by the entry's constraint, whether
    it is active, and the constraint's multiplier slot (-1 where this endpoint does not write it) and new value.
    Nothing is written here, so that a caller's next entry's loads need not wait for a store."""
    entry = fetch(constraints.entries, a)
    j = first + entry[0]
    c = entry[1]
    compliant = c < 0                         # alpha_tilde != 0
    if compliant:
        c = -1 - c
    slot = multipliers + c
    if per_entry:
        slot = multipliers + a
    lam = float(0.0)
    if compliant:
        lam = fetch(sweep.lambda_in, slot) * sweep.lambda_carry
    p = fetch(constraints.params, c)          # rest_min, rest_max, alpha_tilde, scale
    d = xi - fetch(sweep.x_in, j)
    dist = wp.length(d)
    err = dist - wp.clamp(dist, p[0], p[1])
    w_sum = wi + fetch(constraints.inv_mass, entry[0])
    alpha = p[2]
    lam_new = float(0.0)
    term = wp.vec3(0.0)
    active = bool(False)
    if err != 0.0 and w_sum > 0.0 and dist > 1.0e-12:
        d_lambda = p[3] * (-err - alpha * lam) / (w_sum + alpha)
        term = (wi * d_lambda / dist) * d
        lam_new = lam + d_lambda
        active = True
    if not ((i < j or per_entry) and compliant):
        slot = -1
    return term, active, slot, lam_new


@wp.kernel
def solve_distance_constraints(sub: Substep, constraints: DistanceConstraints, sweep: JacobiSweep, lanes: int):
    """One Jacobi sweep over the distance constraints, reading x_in and writing x_out (see distance_correction),
    launched over n * lanes threads: vertex tid // lanes, lane tid % lanes."""
    i, lane = lane_of(wp.tid(), lanes)
    xi = sweep.x_in[i]
    dx = lane_sum_vec3(distance_correction(i, i // sub.world_vertices, xi, sub, constraints, sweep, lane, lanes),
                       lanes)
    if lane == 0:
        sweep.x_out[i] = xi + dx


@wp.func
def store_state(i: int, xi: wp.vec3, sub: Substep):
    """x = xi, v = (xi - x_prev) / h; flags the substep if the position is not finite or the speed exceeds
    `max_speed` (the host turns the flag into an error)."""
    vi = (xi - sub.x_prev[i]) * sub.inv_h
    sub.x[i] = xi
    sub.v[i] = vi
    speed = wp.length(vi)
    if not (speed <= sub.max_speed):  # also true for NaN
        sub.flags[i // sub.world_vertices, sub.index] = 1


@wp.kernel
def update_velocities(sub: Substep, x_solved: wp.array(dtype=wp.vec3)):
    """Copies the solved positions into the state buffer and derives velocities (see store_state)."""
    i = wp.tid()
    store_state(i, x_solved[i], sub)


@wp.kernel
def harmonic_partial_sums(x: wp.array(dtype=wp.vec3), hp: HarmonicProjection):
    """partial[w, c, k] = sum over the rows i of chunk c of (M B)[i, k] x_i in world w: the first half of the
    reduction B^T M x. Threads with consecutive k read consecutive entries of row i, so loads coalesce on GPU."""
    w, c, k = wp.tid()
    n = hp.mass_basis.shape[0]
    start = c * hp.rows_per_chunk
    end = wp.min(start + hp.rows_per_chunk, n)
    first = w * n
    acc = wp.vec3(0.0)
    for i in range(start, end):
        acc = acc + hp.mass_basis[i, k] * x[first + i]
    hp.partial[w, c, k] = acc


@wp.kernel
def harmonic_residual(hp: HarmonicProjection, target_fraction: float, lanes: int):
    """r_k = (B^T M x)_k - (B^T M S x_low)_k of world w, the low-res side interpolated linearly within the frame.
    Launched over B K lanes threads: `lanes` threads share a mode's chunks (lane_sum_vec3)."""
    q, lane = lane_of(wp.tid(), lanes)
    n_modes = hp.residual.shape[1]
    w = q // n_modes
    k = q - w * n_modes
    acc = wp.vec3(0.0)
    for c in range(lane, hp.partial.shape[1], lanes):
        acc = acc + hp.partial[w, c, k]
    acc = lane_sum_vec3(acc, lanes)
    if lane == 0:
        hp.residual[w, k] = acc - wp.lerp(hp.target_start[w, k], hp.target_end[w, k], target_fraction)


@wp.kernel
def harmonic_project(hp: HarmonicProjection, x: wp.array(dtype=wp.vec3), lanes: int):
    """x_i -= sum_k A[i, k] r_k with A = P_free B (B^T M P_free B)^{-1}: the M-orthogonal projection onto
    B^T M (x - S x_low) = 0 that leaves pinned vertices (zero rows of A) where they are. A is stored transposed
    (K, V) so that consecutive vertices read consecutive entries (also with `lanes` threads a vertex, each taking
    every lanes-th mode: a lane's loads across the warp's vertices stay contiguous)."""
    i, lane = lane_of(wp.tid(), lanes)
    n = hp.mass_basis.shape[0]
    w = i // n
    row = i - w * n
    acc = wp.vec3(0.0)
    for k in range(lane, hp.residual.shape[1], lanes):
        acc = acc + hp.correction_basis_t[k, row] * hp.residual[w, k]
    acc = lane_sum_vec3(acc, lanes)
    if lane == 0:
        x[i] = x[i] - acc
