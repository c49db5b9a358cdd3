"""Warp kernels of body contact in the XPBD cloth solver: the cloth against the mannequin's tapered capsules.

The per-vertex work lives inside the solver's existing launches, so the body adds few graph nodes:
- `predict_with_body` replaces `predict_positions`: after the inertial prediction it sweeps each vertex, in the
  frame of each moving capsule, from where it was at the substep start to its prediction, and stops it where it
  first touches (continuous: a limb that moves farther than its radius in a substep cannot pass through the
  cloth); it also lists the few capsules near the vertex for the iterations, which `push_out_of_body` resolves
  inside the Jacobi sweep (`sim.xpbd.contact_sweep`);
- `finish_substep` replaces `update_velocities`: position-based Coulomb friction against the capsule's own
  motion, a last projection out of every capsule, then velocities; `body_friction` and `clear_of_body` are its
  two halves, for the rounds that alternate the body and the harmonic constraint at the end of a high-res substep.
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True})

from sim.xpbd.kernels import PinDrive, Substep, predict_vertex, store_state

SWEEP_STEPS = 24            # sphere-tracing steps of the continuous body test (a head-on approach needs one)
SWEEP_TOLERANCE = 1.0e-3    # the trace has touched when within this fraction of the level
FINAL_PASSES = 3            # passes over all capsules at the end of a substep
WATCHED = 3                 # capsules a vertex may watch in the iterations (a byte each in one int32)


@wp.struct
class CapsuleShape:
    """A tapered capsule at one moment and what its distance function derives from its end points and radii
    (capsule_shape): built once where the capsule is met many times (a sweep's watched capsules, a continuous
    test's trace), not at every distance."""
    a: wp.vec3
    b: wp.vec3
    ra: float
    rb: float
    e: wp.vec3                        # unit axis, a to b
    length: float                     # |b - a|
    sin_phi: float                    # (ra - rb) / length: the taper
    cos_phi: float


@wp.struct
class Capsules:
    """The body as tapered capsules at the start and end of the frame, and per-vertex body-contact state of the
    substep. World w's capsules are rows w P .. w P + P - 1 (P = per_world; 0 without body collision)."""
    start: wp.array2d(dtype=wp.vec3)  # (B P, 2) end points a, b at the start of the frame
    end: wp.array2d(dtype=wp.vec3)    # (B P, 2) at its end
    radius: wp.array2d(dtype=float)   # (B P, 2) radii at a and b
    per_world: int                    # capsules per world
    thickness: float                  # cloth stays this far outside every capsule
    reach: float                      # capsules closer than this to the prediction are watched in the iterations
    friction: float
    near: wp.array(dtype=int)         # (B V,) capsules watched in this substep: c + 1 in each byte (c counted within
                                      # the vertex's world), 0 ends the list
    push: wp.array(dtype=float)       # (B V,) total outward correction by the body in this substep
    shapes: wp.array(dtype=CapsuleShape)  # (B P,) each capsule at the substep's end (capsule_shapes), which the
                                      # sweeps' push_out_of_body reads: derived once a substep, not every sweep


# ---------------------------------------------------------------------------------------------------------------
# Capsule geometry


@wp.func
def any_perpendicular(e: wp.vec3) -> wp.vec3:
    c = wp.cross(e, wp.vec3(1.0, 0.0, 0.0))
    if wp.length(c) < 0.5:
        c = wp.cross(e, wp.vec3(0.0, 1.0, 0.0))
    return wp.normalize(c)


@wp.func
def capsule_shape(a: wp.vec3, b: wp.vec3, ra: float, rb: float) -> CapsuleShape:
    """The capsule with end points a, b and radii ra, rb, ready for shape_distance."""
    shape = CapsuleShape()
    shape.a = a
    shape.b = b
    shape.ra = ra
    shape.rb = rb
    axis = b - a
    shape.length = wp.length(axis)
    shape.e = axis / shape.length
    shape.sin_phi = (ra - rb) / shape.length
    shape.cos_phi = wp.sqrt(1.0 - shape.sin_phi * shape.sin_phi)
    return shape


@wp.func
def shape_distance(p: wp.vec3, shape: CapsuleShape):
    """Signed distance from p to the tapered capsule (convex hull of the spheres (a, ra) and (b, rb)) and the
    outward unit normal there (the distance's gradient): the formula of scenes.capsules.capsule_signed_distance."""
    e = shape.e
    rel = p - shape.a
    s = wp.dot(rel, e)
    radial = rel - s * e
    q = wp.length(radial)
    along = s * shape.cos_phi - q * shape.sin_phi
    if along <= 0.0:
        to_a = wp.length(rel)
        n_a = -e
        if to_a > 0.0:
            n_a = rel / to_a
        return to_a - shape.ra, n_a
    if along >= shape.length * shape.cos_phi:
        rel_b = p - shape.b
        to_b = wp.length(rel_b)
        n_b = e
        if to_b > 0.0:
            n_b = rel_b / to_b
        return to_b - shape.rb, n_b
    r_hat = any_perpendicular(e)  # on the axis every direction away from it is as good
    if q > 1.0e-9 * shape.length:
        r_hat = radial / q
    return s * shape.sin_phi + q * shape.cos_phi - shape.ra, shape.sin_phi * e + shape.cos_phi * r_hat


@wp.func
def capsule_distance(p: wp.vec3, a: wp.vec3, b: wp.vec3, ra: float, rb: float):
    """shape_distance from p to the capsule (a, ra)-(b, rb), for a capsule met once."""
    d, n = shape_distance(p, capsule_shape(a, b, ra, rb))
    return d, n


@wp.func
def segment_point_distance(p0: wp.vec3, p1: wp.vec3, q: wp.vec3) -> float:
    d = p1 - p0
    t = wp.clamp(wp.dot(q - p0, d) / wp.max(wp.dot(d, d), 1.0e-20), 0.0, 1.0)
    return wp.length(p0 + t * d - q)


@wp.func
def first_capsule(i: int, sub: Substep, capsules: Capsules) -> int:
    """Row of the first capsule of vertex i's world."""
    return (i // sub.world_vertices) * capsules.per_world


@wp.func
def capsule_at(capsules: Capsules, c: int, fraction: float):
    """End points of capsule c at `fraction` of the frame (linear interpolation, like the pins)."""
    return (wp.lerp(capsules.start[c, 0], capsules.end[c, 0], fraction),
            wp.lerp(capsules.start[c, 1], capsules.end[c, 1], fraction))


@wp.func
def capsule_shape_at(capsules: Capsules, c: int, fraction: float) -> CapsuleShape:
    """Capsule c's shape at `fraction` of the frame."""
    a, b = capsule_at(capsules, c, fraction)
    return capsule_shape(a, b, capsules.radius[c, 0], capsules.radius[c, 1])


@wp.func
def carry(p: wp.vec3, a0: wp.vec3, b0: wp.vec3, a1: wp.vec3, b1: wp.vec3) -> wp.vec3:
    """Where p ends up if glued to the capsule while it moves from (a0, b0) to (a1, b1): the nearest axis point
    moves with the end points and the offset from it turns by the smallest rotation taking the old axis direction
    to the new one (a capsule's twist about its own axis is not known from its end points and moves no surface)."""
    axis0 = b0 - a0
    axis1 = b1 - a1
    u = wp.clamp(wp.dot(p - a0, axis0) / wp.dot(axis0, axis0), 0.0, 1.0)
    e0 = wp.normalize(axis0)
    e1 = wp.normalize(axis1)
    w = wp.cross(e0, e1)
    rel = p - (a0 + u * axis0)
    w_rel = wp.cross(w, rel)
    # Rodrigues with sin = |w|, cos = e0.e1: R r = r + w x r + w x (w x r) / (1 + cos); a limb cannot turn by
    # half a revolution within a substep, so 1 + cos stays away from 0.
    return a1 + u * axis1 + rel + w_rel + wp.cross(w, w_rel) / wp.max(1.0 + wp.dot(e0, e1), 1.0e-6)


@wp.func
def sweep_out(start: wp.vec3, end: wp.vec3, shape: CapsuleShape, level: float, d_start: float, n_start: wp.vec3):
    """If the segment start -> end (start outside the level set {distance = level}) enters it, move `end` onto
    the tangent plane where it first does and return it with True; otherwise return `end` unchanged and False.
    The entry is found by sphere tracing, which never steps past it because the distance is 1-Lipschitz. d_start,
    n_start: shape_distance at `start`, which the caller has (on a GPU each distance is a chain of dependent square
    roots and divisions, and a vertex resting on a capsule traces from where it starts every sweep)."""
    delta = end - start
    span = wp.length(delta)
    if span <= 1.0e-9:
        return end, False
    d_mid, n_mid = shape_distance(start + 0.5 * delta, shape)
    if d_mid - level > 0.5 * span:  # the whole segment lies in a ball that clears the level set
        return end, False
    t = float(0.0)
    p = start
    d = d_start   # d, n: the distance and normal at p
    n = n_start
    for _ in range(SWEEP_STEPS):
        gap = d - level
        if gap <= SWEEP_TOLERANCE * level:
            break
        t = t + gap / span
        if t >= 1.0:
            return end, False
        p = start + t * delta
        d, n = shape_distance(p, shape)
    # Touching at p (or, after a long grazing trace, close to it): keep `end` on the outer side of the plane.
    depth = wp.dot(n, end - p)
    if depth >= 0.0:
        return end, False
    return end - depth * n, True


@wp.func
def keep_outside(x_from: wp.vec3, x: wp.vec3, shape: CapsuleShape, thickness: float):
    """Move x, reached from x_from (relative to the capsule), to `thickness` outside the capsule, and return it
    with the distance moved. If x_from was clearly outside (more than a quarter of the thickness) the way in is
    swept first, so x stays on the side it came from even where it crossed the capsule's axis; then the nearest
    point projection settles it on the offset surface."""
    d, n = shape_distance(x, shape)
    if d >= thickness and wp.length(x - x_from) < wp.min(shape.ra, shape.rb):
        return x, 0.0  # outside, and too short a way to have passed through (the common case)
    moved = float(0.0)
    d_from, n_from = shape_distance(x_from, shape)
    if d_from > 0.25 * thickness:
        swept, projected = sweep_out(x_from, x, shape, wp.min(thickness, d_from), d_from, n_from)
        if projected:   # else x, d and n hold
            moved = wp.length(swept - x)
            x = swept
            d, n = shape_distance(x, shape)
    if d < thickness:
        x = x + (thickness - d) * n
        moved = moved + (thickness - d)
    return x, moved


@wp.func
def push_out_of_body(i: int, first: int, x_from: wp.vec3, x: wp.vec3, capsules: Capsules) -> wp.vec3:
    """keep_outside for every capsule watched by vertex i (whose world's capsules start at row `first`), one after
    the other, at the substep's end (capsules.shapes); the distances moved add to the vertex's push (the normal
    impulse that friction is limited by)."""
    near = capsules.near[i]
    if near == 0:
        return x
    push = capsules.push[i]   # added to in a register and stored once: no load on the chain of capsules
    pushed = bool(False)
    while near != 0:
        c = first + (near & 255) - 1
        near = near >> 8
        x, moved = keep_outside(x_from, x, capsules.shapes[c], capsules.thickness)
        if moved > 0.0:
            push = push + moved
            pushed = True
    if pushed:
        capsules.push[i] = push
    return x


@wp.func
def apply_friction(i: int, first: int, x: wp.vec3, x_start: wp.vec3, capsules: Capsules, f0: float,
                   f1: float) -> wp.vec3:
    """Position-based Coulomb friction (Macklin et al. 2014, "Unified particle physics", sec. 6.1) against the
    touching capsule: the vertex's displacement relative to where the capsule would have carried it loses its
    tangential part up to friction * push (stick), or that much of it (slide). The tangent plane of a convex body
    lies outside it, so this never pushes the vertex back into the touching capsule."""
    best = int(0)
    best_d = float(1.0e30)
    best_n = wp.vec3(0.0)
    for c in range(first, first + capsules.per_world):
        a, b = capsule_at(capsules, c, f1)
        d, n = capsule_distance(x, a, b, capsules.radius[c, 0], capsules.radius[c, 1])
        if d < best_d:
            best = c
            best_d = d
            best_n = n
    if best_d > 1.01 * capsules.thickness:  # pushed during the substep but no longer touching
        return x
    a0, b0 = capsule_at(capsules, best, f0)
    a1, b1 = capsule_at(capsules, best, f1)
    rel = x - carry(x_start, a0, b0, a1, b1)
    tangential = rel - wp.dot(rel, best_n) * best_n
    slip = wp.length(tangential)
    limit = capsules.friction * capsules.push[i]
    if slip <= limit:
        return x - tangential
    return x - tangential * (limit / slip)


# ---------------------------------------------------------------------------------------------------------------
# Kernels


@wp.kernel
def predict_with_body(sub: Substep, pins: PinDrive, capsules: Capsules):
    """The inertial prediction (predict_vertex, substep from frame fraction f0 to f1), then, per capsule, the
    continuous test: the vertex's start position is carried with the capsule to the substep end, and the path
    from there to the prediction (the vertex's motion relative to the capsule) goes through keep_outside, so a
    limb that moves farther than its radius in a substep still meets the cloth on its front side. The first
    WATCHED capsules within `reach` of the result are watched in the iterations (a list, not a mask, so that an
    iteration costs nothing for the many vertices far from the body); finish_substep checks them all."""
    predict_near_body(wp.tid(), sub, pins, capsules)


@wp.kernel
def capsule_shapes(capsules: Capsules, fraction: float):
    """Every capsule's shape at `fraction` of the frame (the substep's end), for the sweeps' push_out_of_body."""
    c = wp.tid()
    capsules.shapes[c] = capsule_shape_at(capsules, c, fraction)


@wp.func
def predict_near_body(i: int, sub: Substep, pins: PinDrive, capsules: Capsules):
    """predict_with_body of vertex i."""
    xi = predict_vertex(i, sub, pins)
    near = int(0)
    watched = int(0)
    push = float(0.0)
    if sub.inv_mass[i] > 0.0:
        x_start = sub.x_prev[i]
        first = first_capsule(i, sub, capsules)
        for c in range(first, first + capsules.per_world):
            ra = capsules.radius[c, 0]
            rb = capsules.radius[c, 1]
            a0, b0 = capsule_at(capsules, c, sub.f0)
            a1, b1 = capsule_at(capsules, c, sub.f1)
            # Most capsules are far: skip those whose whole sweep over the substep (within a ball around the
            # mean of the four end points) stays farther than `reach` from the vertex's path.
            center = 0.25 * (a0 + b0 + a1 + b1)
            bound = wp.max(wp.max(wp.length(a0 - center), wp.length(b0 - center)),
                           wp.max(wp.length(a1 - center), wp.length(b1 - center)))
            if segment_point_distance(x_start, xi, center) > bound + wp.max(ra, rb) + capsules.reach:
                continue
            shape = capsule_shape(a1, b1, ra, rb)
            xi, moved = keep_outside(carry(x_start, a0, b0, a1, b1), xi, shape, capsules.thickness)
            push = push + moved
            d, n = shape_distance(xi, shape)
            if d < capsules.reach and watched < WATCHED:
                near = near | ((c - first + 1) << (8 * watched))
                watched += 1
    sub.x[i] = xi
    capsules.near[i] = near
    capsules.push[i] = push

@wp.kernel
def finish_substep(sub: Substep, x_solved: wp.array(dtype=wp.vec3), capsules: Capsules, with_friction: int):
    """Friction for vertices the body pushed in this substep (unless `body_friction` applied it already), then a
    nearest-point projection out of every capsule, watched or not: the constraints may have pulled a vertex into
    a capsule it was far from at the prediction, the harmonic projection may have moved it since the last sweep,
    and friction slides it along one capsule's tangent plane, which may enter a neighbouring capsule. Then
    store_state."""
    finish_vertex(wp.tid(), sub, x_solved, capsules, with_friction)


@wp.func
def finish_vertex(i: int, sub: Substep, x_solved: wp.array(dtype=wp.vec3), capsules: Capsules, with_friction: int):
    """finish_substep of vertex i."""
    xi = x_solved[i]
    if sub.inv_mass[i] > 0.0:
        first = first_capsule(i, sub, capsules)
        if with_friction != 0:
            xi = friction_of(i, first, xi, sub, capsules)
        xi = clear_of_capsules(first, xi, sub.f1, capsules)
    store_state(i, xi, sub)


@wp.kernel
def body_friction(sub: Substep, x: wp.array(dtype=wp.vec3), capsules: Capsules):
    """The friction of finish_substep, in place on the solved positions: before the rounds of harmonic and
    capsule projections that end a high-res substep, so that its tangential slide is held to the harmonic
    constraint too (applied after them, friction alone left a residual of ~3e-4 on the CPU pants)."""
    i = wp.tid()
    if sub.inv_mass[i] > 0.0:
        x[i] = friction_of(i, first_capsule(i, sub, capsules), x[i], sub, capsules)


@wp.func
def friction_of(i: int, first: int, x: wp.vec3, sub: Substep, capsules: Capsules) -> wp.vec3:
    """x after friction, for a vertex the body pushed in this substep."""
    if capsules.friction > 0.0:
        if capsules.push[i] > 0.0:
            return apply_friction(i, first, x, sub.x_prev[i], capsules, sub.f0, sub.f1)
    return x


@wp.func
def clear_of_capsules(first: int, x: wp.vec3, fraction: float, capsules: Capsules) -> wp.vec3:
    """x moved to the thickness outside every capsule of its world at `fraction` of the frame, by nearest-point
    projections. Capsules overlap at the joints; in the crook between two, leaving one may enter the other, so
    the capsules take turns a few times (alternating projections converge to the crease)."""
    for _ in range(FINAL_PASSES):
        total = float(0.0)
        for c in range(first, first + capsules.per_world):
            a, b = capsule_at(capsules, c, fraction)
            ra = capsules.radius[c, 0]
            rb = capsules.radius[c, 1]
            if wp.length(x - 0.5 * (a + b)) > 0.5 * wp.length(b - a) + wp.max(ra, rb) + capsules.thickness:
                continue
            x, moved = keep_outside(x, x, capsule_shape(a, b, ra, rb), capsules.thickness)
            total = total + moved
        if total == 0.0:
            break
    return x


@wp.kernel
def clear_of_body(sub: Substep, x: wp.array(dtype=wp.vec3), capsules: Capsules):
    """x (the solved positions) moved clear of the body in place, between harmonic projections."""
    i = wp.tid()
    if sub.inv_mass[i] > 0.0:
        x[i] = clear_of_capsules(first_capsule(i, sub, capsules), x[i], sub.f1, capsules)
