"""Warp kernels of self-contact (vertex-triangle) in the XPBD cloth solver.

Contact candidates are found once per substep (`contact_bounds`, a BVH refit, `find_self_contacts`,
`sort_face_lists`) and resolved in every iteration (`contact_multiplier`, inside the Jacobi sweep of
`sim.xpbd.contact_sweep`). The broad phase is a `wp.Bvh` over the triangles, built once
and refitted per substep, rather than a `wp.HashGrid`: a hash-grid rebuild inside a CUDA graph replays a
host-to-device copy of a descriptor that Warp 1.19 keeps in one static variable per precision, so two grids in one
process (e.g. two solvers) would read each other's descriptor on replay. A refit is a memset and one kernel, safe
to capture, lossless (no cell capacity) and deterministic (min/max bounds, a fixed tree and traversal order).
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True})

from sim.xpbd.fetch import fetch
from sim.xpbd.kernels import Substep

DETECT_SLACK = 0.25         # candidate pairs: barycentric coordinates of the projection down to -DETECT_SLACK
SOLVE_SLACK = 0.05          # active contacts: down to -SOLVE_SLACK, which closes the gaps above convex ridges
MAX_VALENCE = 16            # mesh neighbours of a vertex, at most, with self-collision on
neighbor_list = wp.types.vector(length=MAX_VALENCE, dtype=int)
HIT_BATCH = 48              # BVH hits a vertex collects before testing them (~24 on average on the pants)
hit_list = wp.types.vector(length=HIT_BATCH, dtype=int)


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
    if tri[0] == i or tri[1] == i or tri[2] == i:
        return 0
    # A constant bound, so the loop unrolls and the neighbours stay in registers (indexed at run time, a vector
    # lives in local memory: a load for each of the ~18 comparisons of every box hit).
    for a in range(MAX_VALENCE):
        if a < n_neighbors and (neighbors[a] == tri[0] or neighbors[a] == tri[1] or neighbors[a] == tri[2]):
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
    xa = fetch(x, tri[0])
    xb = fetch(x, tri[1])
    xc = fetch(x, tri[2])
    n, ok = triangle_normal(xa, xb, xc)
    return xa, xb, xc, wp.vec3(fetch(inv_mass, tri[0]), fetch(inv_mass, tri[1]), fetch(inv_mass, tri[2])), n, ok


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
    """Every triangle's box (face_bounds)."""
    face_bounds(wp.tid(), x, x_prev, sc)


@wp.func
def face_bounds(t: int, x: wp.array(dtype=wp.vec3), x_prev: wp.array(dtype=wp.vec3), sc: SelfContacts):
    """Box of triangle t's projection_box at the substep start and at the prediction, padded by `reach` and
    placed at its world's offset; empties the triangle's contact list."""
    tri = sc.faces[t]
    lo, hi = projection_box(x[tri[0]], x[tri[1]], x[tri[2]])
    lo_start, hi_start = projection_box(x_prev[tri[0]], x_prev[tri[1]], x_prev[tri[2]])
    offset = world_offset(t // sc.world_faces, sc)
    sc.face_lower[t] = wp.min(lo, lo_start) - wp.vec3(sc.reach) + offset
    sc.face_upper[t] = wp.max(hi, hi_start) + wp.vec3(sc.reach) + offset
    sc.face_count[t] = 0


@wp.kernel
def find_self_contacts(sub: Substep, sc: SelfContacts, overflow_flag: int):
    """Contact lists: vertex i queries the triangle BVH with its swept box (search_box) and lists each candidate
    triangle t (list_candidate). Runs after the prediction: x holds the predictions, x_prev the substep's start
    positions."""
    i = wp.tid()
    search = start_search(i, sub, sc)
    if sub.inv_mass[i] > 0.0:
        lower, upper = search_box(i, sub, sc)
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
                search = list_candidate(i, hits[h], search, sub, sc, overflow_flag)
    end_search(i, search, sc)


@wp.struct
class Search:
    """One vertex's search in progress: its mesh neighbours (a local copy: contact_side runs for every candidate),
    the range of triangle ids of its world, how many entries its list had in the previous substep, how many it
    has now and how many candidates were found, listed or not."""
    neighbors: neighbor_list
    n_neighbors: int
    own_faces: wp.vec2i
    n_old: int
    count: int
    wanted: int


@wp.func
def start_search(i: int, sub: Substep, sc: SelfContacts) -> Search:
    """Vertex i's search, started: its previous list kept (keep_previous_list), its neighbours and world read
    (vertex_search)."""
    return vertex_search(i, keep_previous_list(i, sub, sc), sub, sc)


@wp.func
def keep_previous_list(i: int, sub: Substep, sc: SelfContacts) -> int:
    """Vertex i's list of the previous substep copied into `previous`, and its length (a pair already in contact
    in the previous substep keeps its side, so a vertex that the iterations left a little on the wrong side of the
    plane is pushed back rather than through); its corner count zeroed (sort_face_list counts the lists of i's
    triangles, after every vertex's search). Pinned vertices list nothing: they take no correction and move no
    triangle, so theirs is not kept."""
    sc.corner_count[i] = 0
    n_old = int(0)
    if sub.inv_mass[i] > 0.0:
        n_old = sc.vertex_count[i]
        for a in range(n_old):
            sc.previous[i, a] = sc.vertex_contacts[i, a]
    return n_old


@wp.func
def vertex_search(i: int, n_old: int, sub: Substep, sc: SelfContacts) -> Search:
    """Vertex i's search, its previous list of n_old entries in `previous`: its neighbours and the range of its
    world's triangles (read for a vertex that is not pinned), nothing listed yet."""
    search = Search()
    search.n_old = n_old
    if sub.inv_mass[i] > 0.0:
        first = sc.edge_offsets[i]
        search.n_neighbors = sc.edge_offsets[i + 1] - first
        for a in range(MAX_VALENCE):   # unrolled, as contact_side reads them
            if a < search.n_neighbors:
                search.neighbors[a] = sc.vertex_neighbors[first + a]
        world = i // sc.world_vertices
        search.own_faces = wp.vec2i(world * sc.world_faces, (world + 1) * sc.world_faces)
    return search


@wp.func
def search_box(i: int, sub: Substep, sc: SelfContacts):
    """Vertex i's box from its start to its prediction at its world's offset: its candidates are the triangles
    whose face_bounds box overlaps it."""
    offset = world_offset(i // sc.world_vertices, sc)
    return wp.min(sub.x_prev[i], sub.x[i]) + offset, wp.max(sub.x_prev[i], sub.x[i]) + offset


@wp.func
def candidate_side(i: int, t: int, search: Search, sub: Substep, sc: SelfContacts) -> int:
    """contact_side of vertex i and triangle t (whose boxes overlap), or the side the pair had in i's previous
    list where it was there."""
    side = contact_side(i, search.neighbors, search.n_neighbors, search.own_faces, t, sub.x, sub.x_prev, sc)
    if side != 0:
        for a in range(search.n_old):
            if wp.abs(sc.previous[i, a]) == t + 1:
                side = wp.sign(sc.previous[i, a])
    return side


@wp.func
def list_candidate(i: int, t: int, search: Search, sub: Substep, sc: SelfContacts, overflow_flag: int) -> Search:
    """Triangle t, whose box overlaps vertex i's: if the pair is a candidate (candidate_side), vertex i lists it
    and adds itself to t's list (a slot taken with an integer atomic; sort_face_list then restores a fixed order).
    A full list drops the rest and raises the world's flags[w, overflow_flag] to the room the fullest list needed
    (the solver then grows the lists to that at once and steps the frame again)."""
    side = candidate_side(i, t, search, sub, sc)
    if side != 0:
        search.wanted += 1
        slot = sc.face_contacts.shape[1]
        need = search.wanted       # the vertex's list full: the room it would have needed
        if search.count < sc.vertex_contacts.shape[1]:
            slot = wp.atomic_add(sc.face_count, t, 1)
            need = slot + 1
        if slot < sc.face_contacts.shape[1]:
            sc.vertex_contacts[i, search.count] = side * (t + 1)
            sc.face_contacts[t, slot] = side * (i + 1)
            search.count += 1
        else:
            wp.atomic_max(sub.flags, i // sc.world_vertices, overflow_flag, need)
    return search


@wp.func
def end_search(i: int, search: Search, sc: SelfContacts):
    """Vertex i's list stored. Triangles in id order rather than the tree's: the sums of the iterations then do
    not depend on the BVH, so a world stepped in a batch (one tree over all worlds) moves exactly as when stepped
    alone, and an exhaustive search (sim.xpbd.block_frame) lists what the tree's does."""
    sort_list(sc.vertex_contacts, i, search.count)
    sc.vertex_count[i] = search.count


@wp.kernel
def widen_lists(lists: wp.array2d(dtype=int), wider: wp.array2d(dtype=int)):
    """Copy contact lists into the first columns of wider ones (the solver growing them after an overflow)."""
    i, a = wp.tid()
    wider[i, a] = lists[i, a]


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
    """Every triangle's list sorted (sort_face_list)."""
    sort_face_list(wp.tid(), sc)


@wp.func
def sort_face_list(t: int, sc: SelfContacts):
    """Sort triangle t's list by vertex, so that the iterations sum the corrections in an order that does not
    depend on which thread took which slot; count the entries at each corner (an integer sum: deterministic)."""
    n = wp.min(sc.face_count[t], sc.face_contacts.shape[1])
    sc.face_count[t] = n
    sort_list(sc.face_contacts, t, n)
    if n > 0:
        tri = sc.faces[t]
        for k in range(3):
            wp.atomic_add(sc.corner_count, tri[k], n)
