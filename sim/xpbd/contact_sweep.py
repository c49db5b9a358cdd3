"""The Jacobi sweep of the XPBD cloth solver with contacts fused in: `solve_with_collisions` replaces
`sim.xpbd.kernels.solve_distance_constraints` when body or self-collision is on. It does the same Jacobi gather,
plus the vertex's self-contacts (`sim.xpbd.self_contact`), then the capsules it watches (`sim.xpbd.body_contact`),
swept from the vertex's previous iterate (a hard, vertex-local constraint applied last, so every iteration ends
outside the body on the side the vertex came from). One launch per iteration, as without contacts.
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True})

from sim.xpbd.body_contact import Capsules, push_out_of_body
from sim.xpbd.fetch import fetch
from sim.xpbd.kernels import (DistanceConstraints, JacobiSweep, Substep, distance_correction, lane_count, lane_of,
                              lane_sum_vec3)
from sim.xpbd.self_contact import SelfContacts, contact_multiplier, contact_triangle


@wp.kernel
def solve_with_collisions(sub: Substep, constraints: DistanceConstraints, sweep: JacobiSweep, sc: SelfContacts,
                          capsules: Capsules, lanes: int):
    """One Jacobi sweep (swept_vertex), launched over n * lanes threads (kernels.lane_sum_vec3): a lane takes every
    lanes-th constraint, contact of the vertex's list and triangle around it, and the first lane writes the
    result."""
    i, lane = lane_of(wp.tid(), lanes)
    x_new = swept_vertex(i, i // sub.world_vertices, lane, lanes, sub, constraints, sweep, sc, capsules)
    if lane == 0:
        sweep.x_out[i] = x_new


@wp.func
def corner_weight(bary: wp.vec3, corner: int) -> float:
    """bary[corner], chosen rather than indexed: a vector indexed at run time lives in local memory (on a GPU, a
    store and a load on the sweep's path)."""
    if corner == 0:
        return bary[0]
    if corner == 1:
        return bary[1]
    return bary[2]


@wp.func
def swept_vertex(i: int, world: int, lane: int, lanes: int, sub: Substep, constraints: DistanceConstraints,
                 sweep: JacobiSweep, sc: SelfContacts, capsules: Capsules) -> wp.vec3:
    """Vertex i after one Jacobi sweep: distance constraints (distance_correction) and self-contacts gathered from
    x_in, then projection out of the capsules. Empty contact lists and no watched capsule leave exactly x_in +
    distance correction, as solve_distance_constraints computes it. This lane's share of the sums; the capsules
    (which add to the vertex's push) in lane 0 alone, whose result is the one to store. `world` is i's (i //
    world_vertices)."""
    x_in = sweep.x_in
    inv_mass = sub.inv_mass
    xi = fetch(x_in, i)
    dx = distance_correction(i, world, xi, sub, constraints, sweep, lane, lanes)
    # Self-contacts, averaged over the active ones (Jacobi mass splitting): as the vertex, then as a corner of the
    # triangles around it (all lists empty with self-collision off; a pinned vertex takes no correction).
    contact = wp.vec3(0.0)
    active = int(0)
    wi = fetch(inv_mass, i)
    for a in range(lane, fetch(sc.vertex_count, i), lanes):
        code = sc.vertex_contacts[i, a]
        xa, xb, xc, w, n, ok = contact_triangle(fetch(sc.faces, wp.abs(code) - 1), x_in, inv_mass)
        if ok:
            dl, bary, on = contact_multiplier(xi, wi, xa, xb, xc, w, n, wp.sign(code), sc.thickness)
            if on:
                contact = contact + (wi * dl * float(wp.sign(code))) * n
                active += 1
    if wi > 0.0 and fetch(sc.corner_count, i) > 0:
        for f in range(fetch(sc.face_offsets, i) + lane, fetch(sc.face_offsets, i + 1), lanes):
            t = fetch(sc.vertex_faces, f)
            if fetch(sc.face_count, t) > 0:
                tri = fetch(sc.faces, t)
                xa, xb, xc, w, n, ok = contact_triangle(tri, x_in, inv_mass)
                if ok:
                    corner = int(0)
                    for k in range(3):
                        if tri[k] == i:
                            corner = k
                    for a in range(sc.face_count[t]):
                        code = sc.face_contacts[t, a]
                        j = wp.abs(code) - 1
                        dl, bary, on = contact_multiplier(fetch(x_in, j), fetch(inv_mass, j), xa, xb, xc, w, n,
                                                          wp.sign(code), sc.thickness)
                        if on:
                            contact = contact - (wi * corner_weight(bary, corner) * dl * float(wp.sign(code))) * n
                            active += 1
    dx = lane_sum_vec3(dx, lanes)
    contact = lane_sum_vec3(contact, lanes)
    active = lane_count(active, lanes)
    if active > 0:
        dx = dx + contact / float(active)
    # The body last, from this vertex's previous iterate, which the previous sweep left outside.
    if lane == 0:
        return push_out_of_body(i, world * capsules.per_world, xi, xi + dx, capsules)
    return xi + dx
