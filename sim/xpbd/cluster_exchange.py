"""Which blocks of a world's cluster read each vertex in a substep's sweeps (sim.xpbd.block_frame), so that a
sweep sends a vertex's new position to those blocks only, and each block expects as many positions as it reads.

Sent to every block, each block received all V positions every sweep: a counted remote store each, the floor of the
exchange (1.28 µs a sweep for the 757-vertex pants on an H200, ~0.77 ms a frame). A block's vertices read far
fewer: their own, their constraints' other ends, the corners and vertices of their contacts (the lists of the
substep); a block ends the substep of the vertices it sweeps, so it reads no other block's last results. Marking
more than a block reads costs only bytes; marking less would leave it a stale position, so the marks follow
contact_sweep.swept_vertex's reads (and kernels.distance_correction's), without their conditions.

Done tokens keep a block from writing a sweep's results into a copy that another block is still reading the sweep
before from: each block sends one, after its sweep, to each block that sends it positions, and waits for one from
each block it sends to. So blocks that exchange nothing (far apart on the mesh) do not wait for each other.
"""
from __future__ import annotations

import warp as wp

wp.set_module_options({"fast_math": True, "enable_backward": False})

from sim.xpbd.fetch import fetch
from sim.xpbd.kernels import DistanceConstraints
from sim.xpbd.self_contact import SelfContacts


@wp.struct
class ClusterExchange:
    """A substep's readers: bit r of readers[i] is set where block r of vertex i's cluster reads it; incoming
    counts the vertices each block reads (so the bytes its sweep barrier expects); bit q of senders[r] is set where
    block r reads a vertex of block q's, and bit r of receivers[q] then too (the blocks a block sends its done
    tokens to, and those whose tokens it waits for). A block sweeps a run of per_block consecutive vertices of its
    world (owner_block)."""
    readers: wp.array(dtype=int)      # (B V,)
    incoming: wp.array(dtype=int)     # (B cluster_blocks,) world w's block r at w * cluster_blocks + r
    senders: wp.array(dtype=int)      # (B cluster_blocks,)
    receivers: wp.array(dtype=int)    # (B cluster_blocks,)
    per_block: int


def vertices_a_block(world_vertices: int, cluster_blocks: int) -> int:
    """A cluster's blocks each sweep a run of this many of the world's vertices (the last block fewer): all blocks
    busy, and the runs follow the mesh's order, so a vertex's neighbours are mostly its block's."""
    return -(-world_vertices // cluster_blocks)


@wp.func
def owner_block(j: int, first: int, exchange: ClusterExchange) -> int:
    """The block of its world's cluster that sweeps vertex j (`first`: the world's first vertex)."""
    return (j - first) // exchange.per_block


@wp.func
def bits_set(mask: int, bits: int) -> int:
    """How many of the low `bits` bits of mask are set."""
    count = int(0)
    for r in range(bits):
        count += (mask >> r) & 1
    return count


@wp.func
def mark_reader(j: int, first: int, rank: int, world: int, cluster_blocks: int, exchange: ClusterExchange):
    """Block `rank` of the world (whose first vertex is `first`) reads vertex j: its bit in j's readers, and the
    first time (the atomic's old value says whether another of the block's vertices marked j before) one more
    incoming vertex for the block and each of the two blocks in the other's senders and receivers."""
    bit = 1 << rank
    old = wp.atomic_or(exchange.readers, j, bit)
    if (old & bit) == 0:
        row = world * cluster_blocks
        wp.atomic_add(exchange.incoming, row + rank, 1)
        owner = owner_block(j, first, exchange)
        wp.atomic_or(exchange.senders, row + rank, 1 << owner)
        wp.atomic_or(exchange.receivers, row + owner, bit)


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
        mark_reader(i, first, rank, world, cluster_blocks, exchange)
    for a in range(fetch(constraints.offsets, own) + lane, fetch(constraints.offsets, own + 1), lanes):
        mark_reader(first + fetch(constraints.entries, a)[0], first, rank, world, cluster_blocks, exchange)
    for a in range(lane, fetch(sc.vertex_count, i), lanes):
        tri = fetch(sc.faces, wp.abs(sc.vertex_contacts[i, a]) - 1)
        for k in range(3):
            mark_reader(tri[k], first, rank, world, cluster_blocks, exchange)
    if fetch(sc.corner_count, i) > 0:   # some triangle around i has contacts (the sweep's own guard)
        for f in range(fetch(sc.face_offsets, i) + lane, fetch(sc.face_offsets, i + 1), lanes):
            t = fetch(sc.vertex_faces, f)
            if fetch(sc.face_count, t) > 0:
                tri = fetch(sc.faces, t)
                for k in range(3):
                    mark_reader(tri[k], first, rank, world, cluster_blocks, exchange)
                for a in range(fetch(sc.face_count, t)):
                    mark_reader(wp.abs(sc.face_contacts[t, a]) - 1, first, rank, world, cluster_blocks, exchange)
