"""The block frame's self-contact search (sim.xpbd.block_frame): every triangle of a world whose box overlaps a
vertex's box is a candidate, found without a tree and spread over the world's threads.

The work is split into (chunk, vertex) pairs, a chunk being CHUNK_FACES consecutive triangles: a pair tests the
chunk's box, and where it meets the vertex's, its triangles' boxes. A vertex searched by one thread took as long as
its longest search (on an H200 the 757-vertex pants waited ~175 µs a substep for its slowest vertex, a quarter of
the frame); spread, a thread takes ~V C / threads pairs, most rejected by the chunk's box. A pair's box hits then go
to its world's queue of candidates (one integer atomic a pair for their slots), and after a barrier the world's
threads test the queue's candidates (contact_side) one a thread in turn: a pair testing its own hits, up to
CHUNK_FACES of them one after another, each a chain of dependent loads, kept every other thread waiting at the
barrier. A pair whose hits do not fit the queue tests them itself, so a full queue costs time, not candidates. A
candidate is listed with integer atomics in both lists, so the lists hold the same entries as the tree's search but
in any order: each is then sorted (self_contact.sort_list), which makes them identical. A full list keeps counting:
the room it needed raises the world's overflow flag, and the solver steps the frame again with longer lists (each
list's entries are real candidates whatever the order, so the frame that overflowed steps safely before it is
discarded). At the lists' largest capacity, where the solver keeps the frame and warns, a pair may be in one of its
two lists only (the tree's search keeps it in both or neither).
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function).
wp.set_module_options({"fast_math": True, "enable_backward": False})

from sim.xpbd.kernels import Substep
from sim.xpbd.self_contact import (SelfContacts, candidate_side, keep_previous_list, search_box, sort_face_list,
                                   sort_list, vertex_search)

# A mesh's triangle ids are close in space, so a vertex's box meets few chunks (the 3.7k-vertex pants hanging: a
# vertex's box meets ~10 of its 225 chunks, at most 26; the paper's 757-vertex pants ~6 of 46). A chunk's box
# holds its triangles' boxes (min and max are exact), so every triangle whose box meets the vertex's is tested.
CHUNK_FACES = 32
# The queue's room a vertex of a world. A vertex's box meets its own ring of triangles (rejected by contact_side
# in a few instructions) and those near it: ~10.5 a vertex on the paper's 757-vertex pants dancing, 19-25 on the
# 3.7k-vertex pants (one substep a frame, CPU). Beyond the room, pairs test their hits themselves.
QUEUE_PER_VERTEX = 48


@wp.struct
class WorldSearch:
    """The search's own arrays: the box of each chunk of CHUNK_FACES consecutive triangles of a world (the last
    may hold fewer), world after world (world w's chunks are rows w C .. w C + C - 1), and the length of each
    vertex's list of the previous substep (kept in SelfContacts.previous while the pairs fill the new one), and
    each world's queue of candidates: `queue_room` entries a world (world w's are rows w R .. w R + R - 1), each a
    vertex and a triangle of the world as one integer (t V + i, both counted within the world; -1 a slot left
    empty), and how many slots its pairs took (past the room: the pairs that tested their own hits)."""
    lower: wp.array(dtype=wp.vec3)
    upper: wp.array(dtype=wp.vec3)
    per_world: int                    # C
    previous_count: wp.array(dtype=int)
    queue: wp.array(dtype=int)
    queue_room: int                   # R
    queue_count: wp.array(dtype=int)


@wp.func
def boxes_overlap(lower: wp.vec3, upper: wp.vec3, box_lower: wp.vec3, box_upper: wp.vec3) -> bool:
    """The BVH query's box test (Warp's intersect_aabb_aabb: closed boxes), so the search finds its hits."""
    return not (lower[0] > box_upper[0] or lower[1] > box_upper[1] or lower[2] > box_upper[2]
                or upper[0] < box_lower[0] or upper[1] < box_lower[1] or upper[2] < box_lower[2])


@wp.func
def start_vertex_list(i: int, sub: Substep, sc: SelfContacts, search: WorldSearch):
    """Vertex i's list of the previous substep kept (self_contact.keep_previous_list) and its new list emptied,
    before the pairs fill it."""
    search.previous_count[i] = keep_previous_list(i, sub, sc)
    sc.vertex_count[i] = 0


@wp.func
def chunk_bounds(c: int, world: int, sc: SelfContacts, search: WorldSearch):
    """The box of chunk c (a row of search.lower/upper) of `world`, from its triangles' face_bounds boxes."""
    start = world * sc.world_faces + (c - world * search.per_world) * CHUNK_FACES
    end = wp.min(start + CHUNK_FACES, (world + 1) * sc.world_faces)
    lower = sc.face_lower[start]
    upper = sc.face_upper[start]
    for t in range(start + 1, end):
        lower = wp.min(lower, sc.face_lower[t])
        upper = wp.max(upper, sc.face_upper[t])
    search.lower[c] = lower
    search.upper[c] = upper


@wp.func
def search_pair(p: int, world: int, sub: Substep, sc: SelfContacts, search: WorldSearch):
    """Pair p of `world` (its chunk p // V, its vertex p % V: a warp's threads test consecutive vertices, which
    meet the same chunks, against one chunk, so the warp runs the chunk's triangles only where one of them meets
    it, and reads each triangle's box once for all): the chunk's triangles whose boxes overlap the vertex's, queued
    as the world's candidates where they fit (test_queued), tested here (test_hits) where they do not."""
    V = sc.world_vertices
    chunk = p // V
    i = world * V + p - chunk * V
    c = world * search.per_world + chunk
    if sub.inv_mass[i] > 0.0:
        lower, upper = search_box(i, sub, sc)
        if boxes_overlap(lower, upper, search.lower[c], search.upper[c]):
            start = world * sc.world_faces + chunk * CHUNK_FACES
            # The boxes first, a bit a triangle, in a loop without calls (its loads overlap).
            hits = int(0)
            count = int(0)
            for k in range(wp.min(CHUNK_FACES, (world + 1) * sc.world_faces - start)):
                if boxes_overlap(lower, upper, sc.face_lower[start + k], sc.face_upper[start + k]):
                    hits = hits | (1 << k)
                    count += 1
            if count > 0:
                slot = wp.atomic_add(search.queue_count, world, count)
                room = (world + 1) * search.queue_room
                slot += world * search.queue_room
                for k in range(CHUNK_FACES):
                    if (hits >> k) & 1 != 0:
                        if slot < room:
                            search.queue[slot] = (chunk * CHUNK_FACES + k) * V + i - world * V
                        slot += 1
                if slot > room:
                    # Past the room: the slots it took below the room stay empty, and the pair tests its hits.
                    for q in range(slot - count, room):
                        search.queue[q] = -1
                    test_hits(i, start, hits, sub, sc, search)


@wp.func
def test_hits(i: int, start: int, hits: int, sub: Substep, sc: SelfContacts, search: WorldSearch):
    """Vertex i against the triangles start + k of the bits k of `hits`: those candidate_side accepts listed in
    both lists (list_pair_candidate)."""
    vertex = vertex_search(i, search.previous_count[i], sub, sc)
    for k in range(CHUNK_FACES):
        if (hits >> k) & 1 != 0:
            side = candidate_side(i, start + k, vertex, sub, sc)
            if side != 0:
                list_pair_candidate(i, start + k, side, sc)


@wp.func
def test_queued(q: int, world: int, sub: Substep, sc: SelfContacts, search: WorldSearch):
    """Slot q of `world`'s queue (q counted within the world, below its queue_count and room): its vertex against
    its triangle, listed in both lists where candidate_side accepts the pair."""
    entry = search.queue[world * search.queue_room + q]
    if entry >= 0:
        V = sc.world_vertices
        t = entry // V
        i = world * V + entry - t * V
        t = t + world * sc.world_faces
        side = candidate_side(i, t, vertex_search(i, search.previous_count[i], sub, sc), sub, sc)
        if side != 0:
            list_pair_candidate(i, t, side, sc)


@wp.func
def list_pair_candidate(i: int, t: int, side: int, sc: SelfContacts):
    """Vertex i lists triangle t and t lists i, each in a slot taken with an integer atomic, written where the list
    has room: a count past the room is the room it needed (end_vertex_list, end_face_list)."""
    slot = wp.atomic_add(sc.vertex_count, i, 1)
    if slot < sc.vertex_contacts.shape[1]:
        sc.vertex_contacts[i, slot] = side * (t + 1)
    slot = wp.atomic_add(sc.face_count, t, 1)
    if slot < sc.face_contacts.shape[1]:
        sc.face_contacts[t, slot] = side * (i + 1)


@wp.func
def end_vertex_list(i: int, world: int, sub: Substep, sc: SelfContacts, overflow_flag: int):
    """Vertex i's list, filled by the pairs, sorted by triangle (self_contact.end_search's order) and cut to its
    room; a count past the room raises the world's overflow flag to it."""
    n = sc.vertex_count[i]
    room = sc.vertex_contacts.shape[1]
    if n > room:
        wp.atomic_max(sub.flags, world, overflow_flag, n)
        n = room
    sort_list(sc.vertex_contacts, i, n)
    sc.vertex_count[i] = n


@wp.func
def end_face_list(t: int, world: int, sub: Substep, sc: SelfContacts, overflow_flag: int):
    """Triangle t's list sorted and its corners counted (self_contact.sort_face_list); a count past the room
    raises the world's overflow flag to it."""
    if sc.face_count[t] > sc.face_contacts.shape[1]:
        wp.atomic_max(sub.flags, world, overflow_flag, sc.face_count[t])
    sort_face_list(t, sc)
