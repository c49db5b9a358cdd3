"""Warp kernels for body contact (tapered capsules) and self-contact (vertex-triangle) in the XPBD cloth solver.

The per-vertex work lives inside the solver's existing launches, so collisions add few graph nodes:
- `predict_with_body` replaces `predict_positions`: after the inertial prediction it sweeps each vertex, in the
  frame of each moving capsule, from where it was at the substep start to its prediction, and stops it where it
  first touches (continuous: a limb that moves farther than its radius in a substep cannot pass through the
  cloth); it also lists the few capsules near the vertex for the iterations;
- `solve_with_collisions` replaces `solve_distance_constraints`: the same Jacobi gather, plus the vertex's
  self-contacts, then the listed capsules, swept from the vertex's previous iterate (a hard, vertex-local
  constraint applied last, so every iteration ends outside the body on the side the vertex came from);
- `finish_substep` replaces `update_velocities`: position-based Coulomb friction against the capsule's own
  motion, a last projection out of every capsule, then velocities.
Self-contact candidates are found once per substep (`contact_bounds`, a BVH refit, `find_self_contacts`,
`sort_face_lists`) and resolved in every iteration. The broad phase is a `wp.Bvh` over the triangles, built once
and refitted per substep, rather than a `wp.HashGrid`: a hash-grid rebuild inside a CUDA graph replays a
host-to-device copy of a descriptor that Warp 1.19 keeps in one static variable per precision, so two grids in one
process (e.g. two solvers) would read each other's descriptor on replay. A refit is a memset and one kernel, safe
to capture, lossless (no cell capacity) and deterministic (min/max bounds, a fixed tree and traversal order).
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True})

from sim.xpbd.kernels import (DistanceConstraints, JacobiSweep, PinDrive, Substep, distance_correction,
                              lane_count, lane_of, lane_sum_vec3, predict_vertex, store_state)

SWEEP_STEPS = 24            # sphere-tracing steps of the continuous body test (a head-on approach needs one)
SWEEP_TOLERANCE = 1.0e-3    # the trace has touched when within this fraction of the level
DETECT_SLACK = 0.25         # candidate pairs: barycentric coordinates of the projection down to -DETECT_SLACK
SOLVE_SLACK = 0.05          # active contacts: down to -SOLVE_SLACK, which closes the gaps above convex ridges
FINAL_PASSES = 3            # passes over all capsules at the end of a substep
WATCHED = 3                 # capsules a vertex may watch in the iterations (a byte each in one int32)
MAX_VALENCE = 16            # mesh neighbours of a vertex, at most, with self-collision on
neighbor_list = wp.types.vector(length=MAX_VALENCE, dtype=int)
HIT_BATCH = 48              # BVH hits a vertex collects before testing them (~24 on average on the pants)
hit_list = wp.types.vector(length=HIT_BATCH, dtype=int)


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


@wp.struct
class SelfContacts:
    """Mesh, broad-phase boxes and contact lists of the substep.

    A contact is a vertex i and a triangle t not near it in the mesh, with the side of t that i was on at the
    substep start. Vertex i lists it as side * (t + 1), triangle t as side * (i + 1): a vertex gathers the
    corrections it receives from its own list and from the lists of the triangles around it, without atomics.

    With several worlds the faces of world w are rows w F .. w F + F - 1 (their vertex ids already those of world
    w), and all worlds share one BVH whose boxes are offset by world_offset: a query meets its own world's
    triangles only, unless a world's cloth strays a lattice spacing from the others' (contact_side then still
    rejects the other world's triangles, so the offset only ever saves time).
    """
    faces: wp.array(dtype=wp.vec3i)
    face_offsets: wp.array(dtype=int)  # CSR of the faces around each vertex
    vertex_faces: wp.array(dtype=int)
    edge_offsets: wp.array(dtype=int)  # CSR of the mesh neighbours of each vertex
    vertex_neighbors: wp.array(dtype=int)
    face_lower: wp.array(dtype=wp.vec3)    # box where points may project into the triangle in the substep
    face_upper: wp.array(dtype=wp.vec3)
    face_bvh: wp.uint64
    vertex_contacts: wp.array2d(dtype=int)  # (V, capacity): a vertex's list of the triangles it touches
    previous: wp.array2d(dtype=int)         # (V, capacity): scratch, a vertex's list of the previous substep
    vertex_count: wp.array(dtype=int)
    face_contacts: wp.array2d(dtype=int)    # (F, capacity): a triangle's list of the vertices touching it
    face_count: wp.array(dtype=int)
    corner_count: wp.array(dtype=int)      # (V,) entries in the lists of the triangles around vertex i: the
                                            # iterations skip those lists where it is 0 (most vertices)
    thickness: float
    reach: float                       # pairs within this distance at the prediction become candidates
    world_vertices: int                # vertices per world
    world_faces: int                   # triangles per world
    lattice: int                       # worlds per lattice row (and per layer: lattice^2)
    spacing: float                     # lattice spacing of the worlds' BVH boxes


# ---------------------------------------------------------------------------------------------------------------
# Capsule geometry


@wp.func
def any_perpendicular(e: wp.vec3) -> wp.vec3:
    c = wp.cross(e, wp.vec3(1.0, 0.0, 0.0))
    if wp.length(c) < 0.5:
        c = wp.cross(e, wp.vec3(0.0, 1.0, 0.0))
    return wp.normalize(c)


@wp.func
def capsule_distance(p: wp.vec3, a: wp.vec3, b: wp.vec3, ra: float, rb: float):
    """Signed distance from p to the tapered capsule (convex hull of the spheres (a, ra) and (b, rb)) and the
    outward unit normal there (the distance's gradient): the formula of scenes.capsules.capsule_signed_distance."""
    axis = b - a
    length = wp.length(axis)
    e = axis / length
    rel = p - a
    s = wp.dot(rel, e)
    radial = rel - s * e
    q = wp.length(radial)
    sin_phi = (ra - rb) / length
    cos_phi = wp.sqrt(1.0 - sin_phi * sin_phi)
    along = s * cos_phi - q * sin_phi
    if along <= 0.0:
        to_a = wp.length(rel)
        n_a = -e
        if to_a > 0.0:
            n_a = rel / to_a
        return to_a - ra, n_a
    if along >= length * cos_phi:
        rel_b = p - b
        to_b = wp.length(rel_b)
        n_b = e
        if to_b > 0.0:
            n_b = rel_b / to_b
        return to_b - rb, n_b
    r_hat = any_perpendicular(e)  # on the axis every direction away from it is as good
    if q > 1.0e-9 * length:
        r_hat = radial / q
    return s * sin_phi + q * cos_phi - ra, sin_phi * e + cos_phi * r_hat


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
def sweep_out(start: wp.vec3, end: wp.vec3, a: wp.vec3, b: wp.vec3, ra: float, rb: float, level: float) -> wp.vec3:
    """If the segment start -> end (start outside the level set {distance = level}) enters it, move `end` onto
    the tangent plane where it first does; otherwise return `end` unchanged. The entry is found by sphere tracing,
    which never steps past it because the distance is 1-Lipschitz."""
    delta = end - start
    span = wp.length(delta)
    if span <= 1.0e-9:
        return end
    d_mid, n_mid = capsule_distance(start + 0.5 * delta, a, b, ra, rb)
    if d_mid - level > 0.5 * span:  # the whole segment lies in a ball that clears the level set
        return end
    t = float(0.0)
    p = start
    for _ in range(SWEEP_STEPS):
        d, n = capsule_distance(p, a, b, ra, rb)
        gap = d - level
        if gap <= SWEEP_TOLERANCE * level:
            break
        t = t + gap / span
        if t >= 1.0:
            return end
        p = start + t * delta
    # Touching at p (or, after a long grazing trace, close to it): keep `end` on the outer side of the plane.
    d_hit, n_hit = capsule_distance(p, a, b, ra, rb)
    depth = wp.dot(n_hit, end - p)
    if depth >= 0.0:
        return end
    return end - depth * n_hit


@wp.func
def keep_outside(x_from: wp.vec3, x: wp.vec3, a: wp.vec3, b: wp.vec3, ra: float, rb: float, thickness: float):
    """Move x, reached from x_from (relative to the capsule), to `thickness` outside the capsule, and return it
    with the distance moved. If x_from was clearly outside (more than a quarter of the thickness) the way in is
    swept first, so x stays on the side it came from even where it crossed the capsule's axis; then the nearest
    point projection settles it on the offset surface."""
    d, n = capsule_distance(x, a, b, ra, rb)
    if d >= thickness and wp.length(x - x_from) < wp.min(ra, rb):
        return x, 0.0  # outside, and too short a way to have passed through (the common case)
    moved = float(0.0)
    d_from, n_from = capsule_distance(x_from, a, b, ra, rb)
    if d_from > 0.25 * thickness:
        swept = sweep_out(x_from, x, a, b, ra, rb, wp.min(thickness, d_from))
        moved = wp.length(swept - x)
        x = swept
        d, n = capsule_distance(x, a, b, ra, rb)
    if d < thickness:
        x = x + (thickness - d) * n
        moved = moved + (thickness - d)
    return x, moved


@wp.func
def push_out_of_body(i: int, first: int, x_from: wp.vec3, x: wp.vec3, capsules: Capsules,
                     fraction: float) -> wp.vec3:
    """keep_outside for every capsule watched by vertex i (whose world's capsules start at row `first`), one after
    the other, at `fraction` of the frame; the distances moved add to the vertex's push (the normal impulse that
    friction is limited by)."""
    near = capsules.near[i]
    while near != 0:
        c = first + (near & 255) - 1
        near = near >> 8
        a, b = capsule_at(capsules, c, fraction)
        x, moved = keep_outside(x_from, x, a, b, capsules.radius[c, 0], capsules.radius[c, 1], capsules.thickness)
        if moved > 0.0:
            capsules.push[i] = capsules.push[i] + moved
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
# Vertex-triangle geometry


@wp.func
def barycentric(r: wp.vec3, e1: wp.vec3, e2: wp.vec3) -> wp.vec3:
    """Barycentric coordinates of the projection of a + r onto the plane of the triangle (a, a + e1, a + e2)."""
    d11 = wp.dot(e1, e1)
    d12 = wp.dot(e1, e2)
    d22 = wp.dot(e2, e2)
    r1 = wp.dot(r, e1)
    r2 = wp.dot(r, e2)
    den = d11 * d22 - d12 * d12
    v = (d22 * r1 - d12 * r2) / den
    w = (d11 * r2 - d12 * r1) / den
    return wp.vec3(1.0 - v - w, v, w)


@wp.func
def triangle_normal(xa: wp.vec3, xb: wp.vec3, xc: wp.vec3):
    """Unit normal and whether the triangle is well enough shaped to have one (slivers are skipped)."""
    e1 = xb - xa
    e2 = xc - xa
    nrm = wp.cross(e1, e2)
    area2 = wp.length(nrm)
    ok = area2 > 1.0e-6 * wp.max(wp.dot(e1, e1), wp.dot(e2, e2))
    if not ok:
        return wp.vec3(0.0), False
    return nrm / area2, True


@wp.func
def contact_side(i: int, neighbors: neighbor_list, n_neighbors: int, own_faces: wp.vec2i, t: int,
                 x: wp.array(dtype=wp.vec3), x_prev: wp.array(dtype=wp.vec3), sc: SelfContacts) -> int:
    """+1 or -1 (the side of t that vertex i was on at the substep start) if (i, t) is a contact candidate, else 0.

    Candidates: t not within one edge of i in the mesh (pairs that close are neighbours at rest, and bending holds
    them apart), and at the prediction i projects into t (down to -DETECT_SLACK) and lies within `reach` of its
    plane, or on the other side than at the start by no more than its motion relative to t (it crossed during the
    prediction). `neighbors` holds i's mesh neighbours (a local copy: this runs for every candidate), `own_faces`
    the range of triangle ids of i's world (two comparisons, not two integer divisions, per candidate: most
    candidates are i's own neighbourhood, rejected within a few instructions)."""
    if t < own_faces[0] or t >= own_faces[1]:
        return 0
    tri = sc.faces[t]
    for k in range(3):
        if tri[k] == i:
            return 0
        for a in range(n_neighbors):
            if neighbors[a] == tri[k]:
                return 0
    xa = x[tri[0]]
    n, ok = triangle_normal(xa, x[tri[1]], x[tri[2]])
    if not ok:
        return 0
    r = x[i] - xa
    bary = barycentric(r, x[tri[1]] - xa, x[tri[2]] - xa)
    if wp.min(bary) < -DETECT_SLACK:
        return 0
    pa = x_prev[tri[0]]
    side = int(1)
    if wp.dot(wp.cross(x_prev[tri[1]] - pa, x_prev[tri[2]] - pa), x_prev[i] - pa) < 0.0:
        side = -1
    d = wp.dot(n, r)
    if wp.abs(d) < sc.reach:
        return side
    # Beyond reach on the other side: a crossing, if the vertex moved that far relative to the triangle (a
    # triangle that turned fast may change the sign without anything crossing).
    moved = x[i] - x_prev[i]
    for k in range(3):
        moved = moved - bary[k] * (x[tri[k]] - x_prev[tri[k]])
    if -float(side) * d < sc.reach + wp.length(moved):
        return side
    return 0


@wp.func
def contact_triangle(tri: wp.vec3i, x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float)):
    """Corners, corner inverse masses, unit normal and whether it has one, of a triangle in a contact."""
    xa = x[tri[0]]
    xb = x[tri[1]]
    xc = x[tri[2]]
    n, ok = triangle_normal(xa, xb, xc)
    return xa, xb, xc, wp.vec3(inv_mass[tri[0]], inv_mass[tri[1]], inv_mass[tri[2]]), n, ok


@wp.func
def contact_multiplier(xi: wp.vec3, wi: float, xa: wp.vec3, xb: wp.vec3, xc: wp.vec3, w: wp.vec3, n: wp.vec3,
                       side: int, thickness: float):
    """Multiplier update, barycentric weights and activity of the contact between vertex i (at xi, inverse mass wi)
    and the triangle (corners xa, xb, xc, inverse masses w, unit normal n) on the given side: the inequality
    side * n . (x_i - sum_k b_k x_k) >= thickness with compliance 0 and the normal held fixed, active while violated
    and while x_i projects into the triangle (down to -SOLVE_SLACK). The vertex moves by wi dl side n, corner k by
    -w_k b_k dl side n. All four vertices evaluate this with the same arguments, so they agree exactly."""
    r = xi - xa
    gap = float(side) * wp.dot(n, r) - thickness
    if gap >= 0.0:
        return 0.0, wp.vec3(0.0), False
    bary = barycentric(r, xb - xa, xc - xa)
    if wp.min(bary) < -SOLVE_SLACK:
        return 0.0, wp.vec3(0.0), False
    bary = wp.max(bary, wp.vec3(0.0))
    bary = bary / (bary[0] + bary[1] + bary[2])
    return -gap / (wi + wp.dot(wp.cw_mul(bary, bary), w)), bary, True


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
    i = wp.tid()
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
            xi, moved = keep_outside(carry(x_start, a0, b0, a1, b1), xi, a1, b1, ra, rb, capsules.thickness)
            push = push + moved
            d, n = capsule_distance(xi, a1, b1, ra, rb)
            if d < capsules.reach and watched < WATCHED:
                near = near | ((c - first + 1) << (8 * watched))
                watched += 1
    sub.x[i] = xi
    capsules.near[i] = near
    capsules.push[i] = push


@wp.func
def projection_box(xa: wp.vec3, xb: wp.vec3, xc: wp.vec3):
    """Box of the points that project into the triangle down to -DETECT_SLACK: the triangle scaled by
    1 + 3 DETECT_SLACK about its centroid."""
    center = (xa + xb + xc) / 3.0
    grow = 1.0 + 3.0 * DETECT_SLACK
    a = center + grow * (xa - center)
    b = center + grow * (xb - center)
    c = center + grow * (xc - center)
    return wp.min(wp.min(a, b), c), wp.max(wp.max(a, b), c)


@wp.func
def world_offset(w: int, sc: SelfContacts) -> wp.vec3:
    """Where world w's boxes sit in the shared BVH: on a lattice `spacing` apart (world 0 at the origin, so a
    single world's boxes are its own). Only the boxes move, never the positions."""
    n = sc.lattice
    return sc.spacing * wp.vec3(float(w % n), float((w // n) % n), float(w // (n * n)))


@wp.kernel
def contact_bounds(x: wp.array(dtype=wp.vec3), x_prev: wp.array(dtype=wp.vec3), sc: SelfContacts):
    """Box of every triangle's projection_box at the substep start and at the prediction, padded by `reach` and
    placed at its world's offset; empties the triangle's contact list."""
    t = wp.tid()
    tri = sc.faces[t]
    lo, hi = projection_box(x[tri[0]], x[tri[1]], x[tri[2]])
    lo_start, hi_start = projection_box(x_prev[tri[0]], x_prev[tri[1]], x_prev[tri[2]])
    offset = world_offset(t // sc.world_faces, sc)
    sc.face_lower[t] = wp.min(lo, lo_start) - wp.vec3(sc.reach) + offset
    sc.face_upper[t] = wp.max(hi, hi_start) + wp.vec3(sc.reach) + offset
    sc.face_count[t] = 0


@wp.kernel
def find_self_contacts(sub: Substep, sc: SelfContacts, overflow_flag: int):
    """Contact lists: vertex i queries the triangle BVH with its swept box and lists each candidate triangle t,
    and adds itself to t's list (a slot taken with an integer atomic; sort_face_lists then restores a fixed order).
    A pair already in contact in the previous substep keeps its side, so a vertex that the iterations left a little
    on the wrong side of the plane is pushed back rather than through. Each list is sorted by triangle, so the
    lists are deterministic and independent of the tree. A full list drops the rest and raises the world's
    flags[w, overflow_flag] (the solver then grows the lists and steps the frame again). Pinned vertices list
    nothing: they take no correction and move no triangle. Runs after the prediction: x holds the
    predictions, x_prev the substep's start positions."""
    i = wp.tid()
    x = sub.x
    x_prev = sub.x_prev
    count = int(0)
    sc.corner_count[i] = 0  # sort_face_lists counts the lists of i's triangles (a later launch)
    if sub.inv_mass[i] > 0.0:
        n_old = sc.vertex_count[i]
        for a in range(n_old):
            sc.previous[i, a] = sc.vertex_contacts[i, a]
        neighbors = neighbor_list()
        first = sc.edge_offsets[i]
        n_neighbors = sc.edge_offsets[i + 1] - first
        for a in range(n_neighbors):
            neighbors[a] = sc.vertex_neighbors[first + a]
        world = i // sc.world_vertices
        own_faces = wp.vec2i(world * sc.world_faces, (world + 1) * sc.world_faces)
        offset = world_offset(world, sc)
        lower = wp.min(x_prev[i], x[i]) + offset
        upper = wp.max(x_prev[i], x[i]) + offset
        # The traversal first, collecting up to HIT_BATCH hits, then the tests of those hits: the two loops
        # interleaved made a warp's threads wait on each other's tests mid-traversal (on an H100 the search took
        # 0.37 ms a substep for the pants, of which the traversal alone is 0.08). A vertex with more hits traverses
        # again for the next batch (the tree's order is fixed, so batch k is hits k HIT_BATCH onwards).
        done = int(0)
        more = int(1)
        while more != 0:
            hits = hit_list()
            n_hits = int(0)
            seen = int(0)
            more = int(0)
            query = wp.bvh_query_aabb(sc.face_bvh, lower, upper)
            t = int(0)
            while wp.bvh_query_next(query, t):
                if seen >= done:
                    if n_hits == HIT_BATCH:
                        more = int(1)
                        break
                    hits[n_hits] = t
                    n_hits += 1
                seen += 1
            done += n_hits
            for h in range(n_hits):
                t = hits[h]
                side = contact_side(i, neighbors, n_neighbors, own_faces, t, x, x_prev, sc)
                if side != 0:
                    for a in range(n_old):
                        if wp.abs(sc.previous[i, a]) == t + 1:
                            side = wp.sign(sc.previous[i, a])
                    slot = sc.face_contacts.shape[1]
                    if count < sc.vertex_contacts.shape[1]:
                        slot = wp.atomic_add(sc.face_count, t, 1)
                    if slot < sc.face_contacts.shape[1]:
                        sc.vertex_contacts[i, count] = side * (t + 1)
                        sc.face_contacts[t, slot] = side * (i + 1)
                        count += 1
                    else:
                        sub.flags[world, overflow_flag] = 1
    # Triangles in id order rather than the tree's: the sums of the iterations then do not depend on the BVH, so a
    # world stepped in a batch (one tree over all worlds) moves exactly as when stepped alone.
    sort_list(sc.vertex_contacts, i, count)
    sc.vertex_count[i] = count


@wp.func
def sort_list(lists: wp.array2d(dtype=int), row: int, n: int):
    """Sort the first n entries of a contact list by the id they name, ignoring the side's sign (insertion sort of
    a few entries)."""
    for a in range(1, n):
        code = lists[row, a]
        b = a
        while b > 0 and wp.abs(lists[row, b - 1]) > wp.abs(code):
            lists[row, b] = lists[row, b - 1]
            b -= 1
        lists[row, b] = code


@wp.kernel
def sort_face_lists(sc: SelfContacts):
    """Sort each triangle's list by vertex, so that the iterations sum the corrections in an order that does not
    depend on which thread took which slot; count the entries at each corner (an integer sum: deterministic)."""
    t = wp.tid()
    n = wp.min(sc.face_count[t], sc.face_contacts.shape[1])
    sc.face_count[t] = n
    sort_list(sc.face_contacts, t, n)
    if n > 0:
        tri = sc.faces[t]
        for k in range(3):
            wp.atomic_add(sc.corner_count, tri[k], n)


@wp.kernel
def solve_with_collisions(sub: Substep, constraints: DistanceConstraints, sweep: JacobiSweep, sc: SelfContacts,
                          capsules: Capsules, lanes: int):
    """One Jacobi sweep: distance constraints (distance_correction) and self-contacts gathered from x_in, then
    projection out of the capsules. Empty contact lists and no watched capsule leave exactly x_in + distance
    correction, as solve_distance_constraints computes it. Launched over n * lanes threads (kernels.lane_sum): a
    lane takes every lanes-th constraint, contact of the vertex's list and triangle around it, and the first lane
    writes the result."""
    i, lane = lane_of(wp.tid(), lanes)
    x_in = sweep.x_in
    inv_mass = sub.inv_mass
    xi = x_in[i]
    dx = distance_correction(i, xi, sub, constraints, sweep, lane, lanes)
    # Self-contacts, averaged over the active ones (Jacobi mass splitting): as the vertex, then as a corner of the
    # triangles around it (all lists empty with self-collision off; a pinned vertex takes no correction).
    contact = wp.vec3(0.0)
    active = int(0)
    wi = inv_mass[i]
    for a in range(lane, sc.vertex_count[i], lanes):
        code = sc.vertex_contacts[i, a]
        xa, xb, xc, w, n, ok = contact_triangle(sc.faces[wp.abs(code) - 1], x_in, inv_mass)
        if ok:
            dl, bary, on = contact_multiplier(xi, wi, xa, xb, xc, w, n, wp.sign(code), sc.thickness)
            if on:
                contact = contact + (wi * dl * float(wp.sign(code))) * n
                active += 1
    if wi > 0.0 and sc.corner_count[i] > 0:
        for f in range(sc.face_offsets[i] + lane, sc.face_offsets[i + 1], lanes):
            t = sc.vertex_faces[f]
            if sc.face_count[t] > 0:
                tri = sc.faces[t]
                xa, xb, xc, w, n, ok = contact_triangle(tri, x_in, inv_mass)
                if ok:
                    corner = int(0)
                    for k in range(3):
                        if tri[k] == i:
                            corner = k
                    for a in range(sc.face_count[t]):
                        code = sc.face_contacts[t, a]
                        j = wp.abs(code) - 1
                        dl, bary, on = contact_multiplier(x_in[j], inv_mass[j], xa, xb, xc, w, n, wp.sign(code),
                                                          sc.thickness)
                        if on:
                            contact = contact - (wi * bary[corner] * dl * float(wp.sign(code))) * n
                            active += 1
    dx = lane_sum_vec3(dx, lanes)
    contact = lane_sum_vec3(contact, lanes)
    active = lane_count(active, lanes)
    if active > 0:
        dx = dx + contact / float(active)
    # The body last, from this vertex's previous iterate, which the previous sweep left outside.
    if lane == 0:
        sweep.x_out[i] = push_out_of_body(i, first_capsule(i, sub, capsules), xi, xi + dx, capsules, sub.f1)


@wp.kernel
def finish_substep(sub: Substep, x_solved: wp.array(dtype=wp.vec3), capsules: Capsules, with_friction: int):
    """Friction for vertices the body pushed in this substep (unless `body_friction` applied it already), then a
    nearest-point projection out of every capsule, watched or not: the constraints may have pulled a vertex into
    a capsule it was far from at the prediction, the harmonic projection may have moved it since the last sweep,
    and friction slides it along one capsule's tangent plane, which may enter a neighbouring capsule. Then
    store_state."""
    i = wp.tid()
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
            x, moved = keep_outside(x, x, a, b, ra, rb, capsules.thickness)
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
            x, moved = keep_outside(x, x, a, b, ra, rb, thickness)
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
