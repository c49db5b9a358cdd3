"""Which blocks of a world's cluster read each vertex in a substep's sweeps (sim.xpbd.block_frame), so that a
sweep sends a vertex's new position to those blocks only, and each block expects as many positions as it reads.

Sent to every block, each block received all V positions every sweep: a counted remote store each, the floor of the
exchange (1.28 µs a sweep for the 757-vertex pants on an H200, ~0.77 ms a frame). A block's vertices read far
fewer: their own, their constraints' other ends, the corners and vertices of their contacts (the lists of the
substep), and the block that ends the substep reads the last sweep's results of the vertices it finishes. Marking
more than a block reads costs only bytes; marking less would leave it a stale position, so the marks follow
contact_sweep.swept_vertex's reads (and kernels.distance_correction's), without their conditions.
"""
from __future__ import annotations

import warp as wp

wp.set_module_options({"fast_math": True, "enable_backward": False})

from sim.xpbd.fetch import fetch
from sim.xpbd.kernels import DistanceConstraints
from sim.xpbd.self_contact import SelfContacts


@wp.struct
class ClusterExchange:
    """A substep's readers: bit r of readers[i] is set where block r of vertex i's cluster reads it, and incoming
    counts the vertices each block reads (so the bytes its sweep barrier expects)."""
    readers: wp.array(dtype=int)      # (B V,)
    incoming: wp.array(dtype=int)     # (B cluster_blocks,) world w's block r at w * cluster_blocks + r


@wp.func
def mark_reader(j: int, rank: int, world: int, cluster_blocks: int, exchange: ClusterExchange):
    """Block `rank` of the world reads vertex j: its bit in j's readers, and one more incoming vertex for the block
    the first time (the atomic's old value says whether another of the block's vertices marked j before)."""
    bit = 1 << rank
    old = wp.atomic_or(exchange.readers, j, bit)
    if (old & bit) == 0:
        wp.atomic_add(exchange.incoming, world * cluster_blocks + rank, 1)


@wp.func
def mark_sweep_reads(i: int, world: int, world_vertices: int, rank: int, cluster_blocks: int, lane: int, lanes: int,
                     constraints: DistanceConstraints, sc: SelfContacts, exchange: ClusterExchange):
    """Every vertex whose position the sweep of vertex i (by block `rank`) reads: i, its constraints' other ends,
    the corners of the triangles in its contact list, and for the triangles around it with contacts their corners
    and listed vertices. This lane's share (every lanes-th of each list: the marks are atomics, each a round trip
    to memory, so a vertex's lanes share them)."""
    first = world * world_vertices
    own = i - first
    if lane == 0:
        mark_reader(i, rank, world, cluster_blocks, exchange)
    for a in range(fetch(constraints.offsets, own) + lane, fetch(constraints.offsets, own + 1), lanes):
        mark_reader(first + fetch(constraints.entries, a)[0], rank, world, cluster_blocks, exchange)
    for a in range(lane, fetch(sc.vertex_count, i), lanes):
        tri = fetch(sc.faces, wp.abs(sc.vertex_contacts[i, a]) - 1)
        for k in range(3):
            mark_reader(tri[k], rank, world, cluster_blocks, exchange)
    if fetch(sc.corner_count, i) > 0:   # some triangle around i has contacts (the sweep's own guard)
        for f in range(fetch(sc.face_offsets, i) + lane, fetch(sc.face_offsets, i + 1), lanes):
            t = fetch(sc.vertex_faces, f)
            if fetch(sc.face_count, t) > 0:
                tri = fetch(sc.faces, t)
                for k in range(3):
                    mark_reader(tri[k], rank, world, cluster_blocks, exchange)
                for a in range(fetch(sc.face_count, t)):
                    mark_reader(wp.abs(sc.face_contacts[t, a]) - 1, rank, world, cluster_blocks, exchange)
