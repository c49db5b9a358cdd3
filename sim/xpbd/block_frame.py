"""A whole frame of the XPBD cloth solver in one kernel launch: world w is a thread block, or a cluster of blocks
(BlockLayout), whose threads share the world's vertices (and triangles) and meet at barriers between the steps
that read what others wrote.

A small cloth is launch-bound in the sweep kernels (`sim.xpbd.solver`: ~600 graph nodes a frame at 8 x 75, ~2 µs
each on an H100, whatever the mesh size); here a sweep costs one barrier. Each step is the sweep path's per-vertex
(per-triangle) function, in the same order, on the same arrays: the prediction (`kernels.predict_vertex`,
`body_contact.predict_near_body`), the self-contact search (`self_contact.face_bounds`, then an exhaustive search of
the world's triangles whose boxes overlap the vertex's box, spread over the world's threads a (chunk of triangles,
vertex) pair a thread and then a candidate a thread: `sim.xpbd.world_search`; it lists the candidates the BVH query
finds, in the same sorted order), the Jacobi sweeps (`contact_sweep.swept_vertex`, `kernels.distance_correction`,
`lanes` threads a vertex as in the sweep kernels) and the substep's end (`body_contact.finish_vertex`,
`kernels.store_state`). So with one lane a vertex the arithmetic is the sweep path's (bit for bit on the CPU, where a
block is one thread).
The sweeps' positions live in shared memory where the world fits (SHARED_VERTICES; a sweep's gather is a chain of
dependent loads, each ~30 cycles there against several hundred from L2, where the last sweep's writes went); a
larger world's stay in global memory (a block's writes before a barrier are visible to the block after it). The
functions are unchanged either way: they index the Jacobi sweep's x_in and x_out, which then view shared memory.
One multiprocessor has too few lanes for a sweep with contacts, so on a GPU with thread block clusters (compute
capability 9.0) a world in shared memory spans a cluster of blocks, each on its own multiprocessor with its own
copy of the positions: a sweep's results are written into the copies of the blocks that read them (distributed
shared memory; sim.xpbd.cluster_exchange), the steps
between sweeps meet at cluster barriers and the sweeps at transaction barriers (see sweep_barrier). The harmonic
projection (a reduction over the world) is not done here: a high-res run keeps the sweep kernels.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function). No
# adjoint: nothing differentiates a frame, and the kernel's backward pass would double its compile time.
wp.set_module_options({"fast_math": True, "enable_backward": False})

from sim.xpbd.body_contact import Capsules, capsule_shape_at, finish_vertex, predict_near_body
from sim.xpbd.cluster_exchange import ClusterExchange, bits_set, mark_sweep_reads, vertices_a_block
from sim.xpbd.contact_sweep import swept_vertex
from sim.xpbd.kernels import (DistanceConstraints, JacobiSweep, PinDrive, Substep, distance_correction,
                              lane_first_vec3, lane_of, lane_sum_vec3, predict_vertex, store_state)
from sim.xpbd.self_contact import SelfContacts, face_bounds
from sim.xpbd.world_search import (WorldSearch, chunk_bounds, end_face_list, end_vertex_list, search_pair,
                                   start_vertex_list, test_queued)

# The most threads a block (one world) runs: the kernel is compiled for it (__launch_bounds__, which caps its
# registers at 64 a thread), and a block of fewer threads takes several vertices a thread.
MAX_BLOCK_THREADS = 1024
WARP_THREADS = 32   # a block's threads are scheduled (and meet its barriers) a warp at a time
# The most vertices a world may have to be stepped in one block (a few per thread); larger cloths keep the sweep
# kernels, which spread a sweep over the whole GPU.
MAX_BLOCK_VERTICES = 4096
# The most vertices a world may have for its sweeps' positions to live in shared memory on CUDA: two buffers of a
# 16-byte slot a vertex (a vec3 and 4 bytes of padding), 43.75 KB: within the 48 KB a block may declare statically,
# beside Warp's own 4 KB at 1,024 threads a block (at 1,408 vertices ptxas refused that block). 16 bytes, not 12: a
# cluster sends a vertex to another block as one 16-byte store, where three 4-byte stores cost ~1.3 µs more a sweep
# (757-vertex pants, stretch only, H200: a sweep's remote stores are counted transactions, each block receiving all
# V of them).
SHARED_VERTICES = 1400
SLOT_BYTES = wp.constant(16)


# Thread block clusters (compute capability 9.0 and later): a world of up to this many blocks, each on its own
# multiprocessor. One multiprocessor has too few lanes for a cloth's sweep with contacts (docs/performance.md, "One
# launch a frame"); a cluster's blocks meet at hardware barriers and write into each other's shared memory. 16 is
# the non-portable size Hopper and Blackwell's data-centre parts launch; others stop at the portable 8.
MAX_CLUSTER_BLOCKS = 16
PORTABLE_CLUSTER_BLOCKS = 8
LANE_CHOICES = (1, 2, 4, 8, 16)


@dataclass(frozen=True)
class BlockLayout:
    """How a world's frame is spread over threads: `threads` a block, `cluster_blocks` blocks a world (a thread
    block cluster on CUDA, each block keeping a copy of the world's positions in its shared memory), `lanes`
    threads a vertex in the Jacobi sweeps (kernels.lane_sum_vec3). A block predicts, sweeps and ends the substep of
    its own run of the world's vertices (a vertex's first lane outside the sweeps); the search's steps take a
    triangle, chunk, pair or candidate a thread of the world."""
    threads: int
    cluster_blocks: int = 1
    lanes: int = 1

    def __str__(self) -> str:
        return f"{self.threads}x{self.cluster_blocks}x{self.lanes}"

    @staticmethod
    def from_text(text: str) -> "BlockLayout":
        """"THREADS[xCLUSTER_BLOCKS[xLANES]]", as str() writes it (benches' arguments)."""
        parts = text.split("x")
        if not 1 <= len(parts) <= 3 or not all(part.isdigit() for part in parts):
            raise ValueError(f"a block layout is THREADS[xCLUSTER_BLOCKS[xLANES]], e.g. 128x8x4; got {text!r}")
        return BlockLayout(*(int(part) for part in parts))


# A cluster's blocks and lanes by default: on an H200, the 757-vertex pants at 8 x 75 with body and self-contact
# step fastest with 16 blocks, 8 lanes a vertex (a vertex a group) and the block's threads fitted to its run of
# vertices (48 x 8 = 384: no idle warp at the block's barriers, and a thread may keep 162 registers and no stack,
# where 512 threads cap it at 128 with an 80-byte stack, sm_90; 512 threads measured the same with self-contact,
# 3-5 % slower without): 3.2 ms a frame against 3.85 with 256 threads and 4 lanes and 4.5 with 256 threads and 8
# (ba5082b, 913a93f), the best of the 14 layouts timed before the gather took two
# entries a turn (docs/performance.md, "One launch a frame"). 8 lanes where they fit blocks of
# CLUSTER_LANES_THREADS threads (a vertex a group), else 4: at 1,024 threads a block a thread may have 64
# registers, and the frame spills more.
CLUSTER_LANES = (8, 4)
CLUSTER_LANES_THREADS = 512


def clusters_serve(device: wp.Device, world_vertices: int) -> bool:
    """Whether a world may span a thread block cluster: a GPU with clusters (compute capability 9.0 and later) and
    the world's positions in shared memory (at most SHARED_VERTICES)."""
    return device.is_cuda and device.arch >= 90 and world_vertices <= SHARED_VERTICES


def default_layout(world_vertices: int, worlds: int, device: wp.Device) -> BlockLayout:
    """One thread a block on the CPU (Warp's fibers take turns only with enable_cpu_blocks). On CUDA, a world in
    shared memory on a GPU with clusters: a cluster a world, as many blocks as fill the multiprocessors once (a
    power of two, at most MAX_CLUSTER_BLOCKS, PORTABLE_CLUSTER_BLOCKS but on Hopper and Blackwell's data-centre
    parts), the first of CLUSTER_LANES lanes a vertex whose groups fit blocks of CLUSTER_LANES_THREADS (the last if
    none does), and threads enough for a block's run of vertices (cluster_exchange.vertices_a_block) in whole warps,
    up to MAX_BLOCK_THREADS; else one block of a thread a vertex (up to MAX_BLOCK_THREADS)."""
    if not device.is_cuda:
        return BlockLayout(threads=1)
    if clusters_serve(device, world_vertices):
        most = MAX_CLUSTER_BLOCKS if device.arch in (90, 100) else PORTABLE_CLUSTER_BLOCKS
        blocks = 1
        while 2 * blocks <= most and 2 * blocks * worlds <= device.sm_count:
            blocks *= 2
        lanes = next((lanes for lanes in CLUSTER_LANES if world_vertices * lanes <= blocks * CLUSTER_LANES_THREADS),
                     CLUSTER_LANES[-1])
        group_threads = vertices_a_block(world_vertices, blocks) * lanes
        return BlockLayout(min(MAX_BLOCK_THREADS, WARP_THREADS * -(-group_threads // WARP_THREADS)), blocks, lanes)
    return BlockLayout(threads=min(MAX_BLOCK_THREADS, 32 * -(-world_vertices // 32)))


def checked_layout(layout: BlockLayout, device: wp.Device, world_vertices: int) -> BlockLayout:
    """`layout`, or a ValueError that says what it may be on `device` for a world of `world_vertices`."""
    if not isinstance(layout, BlockLayout):
        raise ValueError(f"block_layout must be a BlockLayout, got {type(layout).__name__}")
    values = (layout.threads, layout.cluster_blocks, layout.lanes)
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        raise ValueError(f"block_layout's threads, cluster_blocks and lanes must be integers, got {values}")
    if not 1 <= layout.threads <= MAX_BLOCK_THREADS:
        raise ValueError(f"block_layout.threads must be 1 to {MAX_BLOCK_THREADS}, got {layout.threads}")
    lanes = LANE_CHOICES if device.is_cuda else (1,)
    if layout.lanes not in lanes or layout.threads % layout.lanes:
        raise ValueError(f"block_layout.lanes must be one of {lanes} on {device} and divide the threads, got "
                         f"{layout.lanes} lanes of {layout.threads} threads")
    clusters = clusters_serve(device, world_vertices)
    if layout.cluster_blocks != 1 and not (clusters and 1 <= layout.cluster_blocks <= MAX_CLUSTER_BLOCKS):
        raise ValueError(f"block_layout.cluster_blocks must be 1 here, or up to {MAX_CLUSTER_BLOCKS} on a GPU with "
                         f"thread block clusters (compute capability 9.0) for a world of at most {SHARED_VERTICES} "
                         f"vertices; got {layout.cluster_blocks} on {device}")
    return layout


@wp.func_native("""
#if defined(__CUDA_ARCH__)
#if __CUDA_ARCH__ >= 900
    if (cluster_blocks > 1) {
        // release/acquire at cluster scope: the cluster's writes before it, to shared memory anywhere in the
        // cluster and to global memory, are seen by every thread of the cluster after it
        asm volatile("barrier.cluster.arrive.release;\\n\\tbarrier.cluster.wait.acquire;" ::: "memory");
        return;
    }
#endif
    __syncthreads();
#else
    WP_TILE_SYNC();
#endif
""")
def world_barrier(cluster_blocks: int):
    """Every thread of the world (its block, or the `cluster_blocks` blocks of its cluster) waits here until all
    have arrived, and sees their writes before it. On the CPU a block is one thread (nothing to wait for), or with
    warp.config.enable_cpu_blocks as many fibers, which take turns at the barriers (what the tests use to check the
    barriers without a GPU)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __shared__ alignas(16) wp::vec4 buffer[2 * {SHARED_VERTICES}];
    if (in_shared) {
        wp::array_t<wp::vec3> view = fallback;
        view.data = reinterpret_cast<wp::vec3*>(buffer + half * {SHARED_VERTICES} - first);
        view.strides[0] = {SLOT_BYTES};
        return view;
    }
#endif
    return fallback;
""".replace("{SHARED_VERTICES}", str(SHARED_VERTICES)).replace("{SLOT_BYTES}", str(SLOT_BYTES)))
def shared_positions(fallback: wp.array(dtype=wp.vec3), half: int, first: int,
                     in_shared: int) -> wp.array(dtype=wp.vec3):
    """With in_shared (CUDA), a view of half `half` (0 or 1) of the block's shared buffer indexed by the world's
    vertex ids (`first`, the world's first, is its first entry), a vertex every SLOT_BYTES (the array's stride, so
    the functions that index it need not know); else `fallback`, the global buffer."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    if (cluster_blocks > 1) {
        // positions is a view of this block's shared memory: write the same place in every block of the cluster
        // (mapa: the address of that place in block `rank`'s shared memory, within the cluster's window)
        unsigned long long own = reinterpret_cast<unsigned long long>(wp::address(positions, i));
        for (int rank = 0; rank < cluster_blocks; ++rank) {
            unsigned long long copy;
            asm volatile("mapa.u64 %0, %1, %2;" : "=l"(copy) : "l"(own), "r"(rank));
            *reinterpret_cast<wp::vec3*>(copy) = value;
        }
        return;
    }
#endif
    *wp::address(positions, i) = value;
""")
def store_position(positions: wp.array(dtype=wp.vec3), i: int, value: wp.vec3, cluster_blocks: int):
    """positions[i] = value, in every block's copy where a world is a cluster of blocks (each holding the
    positions in its shared memory: shared_positions), so that a sweep's gathers stay in the block's own
    memory."""
    ...


# A cluster's sweeps meet at no barrier. Each block's shared memory holds two transaction barriers (mbarriers), one
# for even sweeps and one for odd ones: a sweep's result goes to the copy of each block that reads it
# (cluster_exchange) by asynchronous remote stores (st.async) that count their bytes on the receiving block's barrier
# of that sweep, each block then sends a done token (send_done) on the same barrier to each block that sends it
# positions, and a block starts the next sweep once the positions it reads and the tokens of the blocks it sends to
# have arrived. A cluster barrier (barrier.cluster) would do too, but with a GPU-wide memory fence and a flush of the
# L1 cache every sweep (~4.6 µs a sweep for the 757-vertex pants on an H200, stretch only). Two barriers suffice: a
# block sends sweep k + 1 to another only after that one's token of sweep k, which means it is done reading the
# buffer that sweep k + 1 writes and has finished waiting on its barrier of sweep k - 1 (the same parity); a token
# of sweep k comes after its sender's wait for sweep k - 1, which needed the positions of sweep k - 1 that its
# receiver sent after finishing its own wait for sweep k - 2. Only positions cross blocks in a sweep: the
# multipliers are per entry (each thread keeps its own, kernels.distance_correction) and the capsules' push is read
# after the substep's last sweep, past a cluster barrier.
@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    __shared__ alignas(8) unsigned long long barriers[2];
    return (int)__cvta_generic_to_shared(&barriers[k & 1]);
#else
    return 0;
#endif
""")
def sweep_barrier(k: int) -> int:
    """The shared-memory address of this block's transaction barrier of sweep k (CUDA; 0 on the CPU)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    if (cluster_blocks > 1 && threadIdx.x == 0) {
        // one arrival a phase (thread 0's, with the bytes it expects); visible to the cluster's st.async after the
        // cluster barrier that follows
        asm volatile("mbarrier.init.shared::cta.b64 [%0], 1;" :: "r"(even_barrier) : "memory");
        asm volatile("mbarrier.init.shared::cta.b64 [%0], 1;" :: "r"(odd_barrier) : "memory");
        asm volatile("fence.mbarrier_init.release.cluster;" ::: "memory");
    }
#endif
""")
def init_sweep_barriers(cluster_blocks: int, even_barrier: int, odd_barrier: int):
    """Thread 0 of each block sets up its two transaction barriers (before the kernel's first cluster barrier)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    if (cluster_blocks > 1) {
        // the vertex's lanes share the sends: lane l writes blocks l, l + lanes, ... of those that read it
        unsigned int own = (unsigned int)__cvta_generic_to_shared(wp::address(positions, i));
        for (int rank = lane; rank < cluster_blocks; rank += lanes) {
            if (!((readers >> rank) & 1))
                continue;
            unsigned int place, arrivals;
            asm volatile("mapa.shared::cluster.u32 %0, %1, %2;" : "=r"(place) : "r"(own), "r"(rank));
            asm volatile("mapa.shared::cluster.u32 %0, %1, %2;" : "=r"(arrivals) : "r"(barrier), "r"(rank));
            // the vertex's whole 16-byte slot in one store (its padding zero)
            asm volatile("st.async.shared::cluster.mbarrier::complete_tx::bytes.v4.b32 [%0], {%1, %2, %3, %4}, [%5];"
                         :: "r"(place), "r"(__float_as_uint(value[0])), "r"(__float_as_uint(value[1])),
                            "r"(__float_as_uint(value[2])), "r"(0u), "r"(arrivals) : "memory");
        }
        return;
    }
#endif
    if (lane == 0)
        *wp::address(positions, i) = value;
""")
def send_position(positions: wp.array(dtype=wp.vec3), i: int, value: wp.vec3, cluster_blocks: int, barrier: int,
                  lane: int, lanes: int, readers: int):
    """A sweep's positions[i] = value, from every lane of vertex i (all holding `value`): in a cluster into the copy
    of each block that reads it (bit r of `readers`: cluster_exchange), counted on each one's `barrier` (its
    sweep_barrier of this sweep); else a plain store."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    __shared__ alignas(16) unsigned int token[4];
    __syncthreads();   // every thread of the block is done with the sweep's input
    if (threadIdx.x < cluster_blocks && ((to >> threadIdx.x) & 1)) {
        unsigned int own = (unsigned int)__cvta_generic_to_shared(token), place, arrivals;
        asm volatile("mapa.shared::cluster.u32 %0, %1, %2;" : "=r"(place) : "r"(own), "r"(threadIdx.x));
        asm volatile("mapa.shared::cluster.u32 %0, %1, %2;" : "=r"(arrivals) : "r"(barrier), "r"(threadIdx.x));
        asm volatile("st.async.shared::cluster.mbarrier::complete_tx::bytes.v4.b32 [%0], {%1, %1, %1, %1}, [%2];"
                     :: "r"(place), "r"(0u), "r"(arrivals) : "memory");
    }
#endif
""")
def send_done(cluster_blocks: int, barrier: int, to: int):
    """A cluster's block says it is done reading a sweep's input: once all its threads are (a block barrier), one
    16-byte token to each block of bit r of `to` (those that send it positions: ClusterExchange.senders), counted on
    its `barrier` with the positions. A block that sends another positions waits for its token, so it never writes
    the next sweep's results into a copy that the other is still reading; blocks that exchange nothing do not wait
    for each other."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
    if (threadIdx.x == 0)
        asm volatile("{ .reg .b64 state; mbarrier.arrive.expect_tx.shared::cta.b64 state, [%0], %1; }"
                     :: "r"(barrier), "r"(bytes) : "memory");
    unsigned int done = 0;
    for (unsigned int tries = 0; !done; ++tries) {
        asm volatile("{ .reg .pred p; mbarrier.try_wait.parity.shared::cta.b64 p, [%1], %2; selp.u32 %0, 1, 0, p; }"
                     : "=r"(done) : "r"(barrier), "r"(parity) : "memory");
        // bytes that never come (a count that does not match the sends) would hang the GPU: fail the launch instead
        if (tries == (1u << 28))
            __trap();
    }
#endif
""")
def wait_for_sweep(barrier: int, parity: int, bytes: int):
    """A cluster's end of a sweep: wait until `bytes` (the positions this block reads and the done tokens of the
    blocks it sends to) have arrived on this block's `barrier` in its phase of this `parity`."""
    ...


@wp.func
def in_buffers(sweep: JacobiSweep, k: int, even: wp.array(dtype=wp.vec3),
               odd: wp.array(dtype=wp.vec3)) -> JacobiSweep:
    """Sweep k reading from and writing to `even` and `odd` in turn (k even: from `even`), as the solver's sweeps
    ping-pong between the state's positions and a work array."""
    moved = sweep
    if k % 2 == 0:
        moved.x_in = even
        moved.x_out = odd
    else:
        moved.x_in = odd
        moved.x_out = even
    return moved


def _step_frame(substeps: wp.array(dtype=Substep), pins: PinDrive, constraints: DistanceConstraints,
                sweeps: wp.array(dtype=JacobiSweep), sc: SelfContacts, search: WorldSearch, capsules: Capsules,
                exchange: ClusterExchange, body_collision: int, self_collision: int, in_shared: int,
                cluster_blocks: int, lanes: int):
    """Every substep of a frame for one world (launch_tiled over the worlds' blocks): the launches of
    ClothSolver._launch_frame without harmonic projection, each a loop of the world's threads over its vertices or
    triangles, a barrier after each that others read from. `substeps` and `sweeps` are the structs the sweep
    kernels are launched with, one per substep and per iteration; with in_shared their positions ping-pong in
    shared memory instead of the state's positions and the work array. A world is `cluster_blocks` consecutive
    blocks (a thread block cluster on CUDA, each block with a copy of the positions in shared memory); in its
    sweeps `lanes` threads share a vertex (kernels.lane_sum_vec3), as in the sweep kernels, and a sweep's result goes
    only to the blocks that read it (cluster_exchange, marked once a substep after the search)."""
    block, block_thread = wp.tid()
    world = block // cluster_blocks
    rank = block - world * cluster_blocks    # the block's within its world
    thread = rank * wp.block_dim() + block_thread   # within the world
    threads = cluster_blocks * wp.block_dim()
    n = substeps[0].world_vertices
    first, last = world * n, (world + 1) * n
    # The block's own run of the world's vertices, the same size in every block (cluster_exchange.owner_block):
    # it predicts, sweeps and finishes them, `lanes` threads a vertex (the lanes after the first idle outside the
    # sweeps), so that a vertex's prediction, sweeps and end are one thread's (no barrier between a substep's end
    # and the next prediction) and its neighbours mostly the block's own.
    own_first = wp.min(first + rank * exchange.per_block, last)
    own_last = wp.min(own_first + exchange.per_block, last)
    item, lane = lane_of(block_thread, lanes)
    items = wp.block_dim() // lanes
    collide = body_collision != 0 or self_collision != 0
    overflow_flag = substeps.shape[0]
    iterations = sweeps.shape[0]
    even = shared_positions(sweeps[0].x_in, 0, first, in_shared)
    odd = shared_positions(sweeps[0].x_out, 1, first, in_shared)
    even_barrier, odd_barrier = sweep_barrier(0), sweep_barrier(1)
    init_sweep_barriers(cluster_blocks, even_barrier, odd_barrier)
    world_barrier(cluster_blocks)   # a cluster's blocks have all started before one writes to another's memory
    for s in range(substeps.shape[0]):
        sub = substeps[s]
        if cluster_blocks > 1 and block_thread == 0:
            exchange.incoming[block] = 0
            exchange.senders[block] = 0
            exchange.receivers[block] = 0
        for c in range(world * capsules.per_world + thread, (world + 1) * capsules.per_world, threads):
            # Read by the sweeps only, past the barrier: the end of the substep must derive its own, as a thread
            # that has finished its vertices rewrites these for the next substep with no barrier between.
            capsules.shapes[c] = capsule_shape_at(capsules, c, sub.f1)
        for i in range(own_first + item, own_last, items):
            if lane == 0:
                if body_collision != 0:
                    predict_near_body(i, sub, pins, capsules)
                else:
                    sub.x[i] = predict_vertex(i, sub, pins)
                store_position(even, i, sub.x[i], cluster_blocks)   # the first sweep's input
                if cluster_blocks > 1:
                    exchange.readers[i] = 0
                if self_collision != 0:
                    start_vertex_list(i, sub, sc, search)
        world_barrier(cluster_blocks)
        if self_collision != 0:
            faces = sc.world_faces
            for t in range(world * faces + thread, (world + 1) * faces, threads):
                face_bounds(t, sub.x, sub.x_prev, sc)
            world_barrier(cluster_blocks)
            for c in range(world * search.per_world + thread, (world + 1) * search.per_world, threads):
                chunk_bounds(c, world, sc, search)
            world_barrier(cluster_blocks)
            for p in range(thread, n * search.per_world, threads):
                search_pair(p, world, sub, sc, search)
            world_barrier(cluster_blocks)
            for q in range(thread, wp.min(search.queue_count[world], search.queue_room), threads):
                test_queued(q, world, sub, sc, search)
            world_barrier(cluster_blocks)
            if thread == 0:
                search.queue_count[world] = 0   # for the next substep's pairs, past the barriers between
            for i in range(first + thread, last, threads):
                end_vertex_list(i, world, sub, sc, overflow_flag)
            for t in range(world * faces + thread, (world + 1) * faces, threads):
                end_face_list(t, world, sub, sc, overflow_flag)
            world_barrier(cluster_blocks)
        incoming_bytes = int(0)
        token_to = int(0)
        if cluster_blocks > 1:
            for i in range(own_first + item, own_last, items):
                mark_sweep_reads(i, world, n, rank, cluster_blocks, lane, lanes, constraints, sc, exchange)
            world_barrier(cluster_blocks)
            # the positions it reads, and a done token from each block it sends to; its own tokens go to the
            # blocks that send to it
            tokens = bits_set(exchange.receivers[block], cluster_blocks)
            incoming_bytes = (exchange.incoming[block] + tokens) * SLOT_BYTES
            token_to = exchange.senders[block]
        for k in range(iterations):
            sweep = in_buffers(sweeps[k], k, even, odd)
            phase = s * iterations + k   # the sweep's number in the frame: its barrier and, per barrier, its parity
            # (chosen, not indexed: a vector indexed at run time lives in local memory, a load on every sweep)
            barrier = even_barrier
            if phase % 2 == 1:
                barrier = odd_barrier
            for i in range(own_first + item, own_last, items):   # a vertex's lanes take the same turns
                xi = sweep.x_in[i]
                x_new = xi
                if collide:
                    x_new = swept_vertex(i, world, lane, lanes, sub, constraints, sweep, sc, capsules)
                else:
                    dx = distance_correction(i, world, xi, sub, constraints, sweep, lane, lanes)
                    x_new = xi + lane_sum_vec3(dx, lanes)
                # lane 0's result (the body's push is its alone) to every lane, which share the sends
                send_position(sweep.x_out, i, lane_first_vec3(x_new, lanes), cluster_blocks, barrier,
                              lane, lanes, exchange.readers[i])
            if cluster_blocks > 1:
                send_done(cluster_blocks, barrier, token_to)
                wait_for_sweep(barrier, (phase // 2) % 2, incoming_bytes)
            else:
                world_barrier(cluster_blocks)
        if cluster_blocks > 1:
            world_barrier(cluster_blocks)   # the last sweep's push on the capsules, read by other blocks below
        # A vertex's end of the substep and next prediction read and write its own entries only (the prediction
        # writes vertex i into every block's copy, but the others read only their own vertices there until the next
        # barrier).
        solved = in_buffers(sweeps[iterations - 1], iterations - 1, even, odd).x_out
        for i in range(own_first + item, own_last, items):
            if lane == 0:
                if collide:
                    finish_vertex(i, sub, solved, capsules, 1)
                else:
                    store_state(i, solved[i], sub)


@functools.cache
def _frame_kernel(cluster_blocks: int, max_threads: int) -> wp.Kernel:
    # block_dim in the module's options: Warp sizes its own shared memory by it (what the 48 KB must hold)
    return wp.kernel(_step_frame, name=f"step_frame_{cluster_blocks}x{max_threads}", launch_bounds=max_threads,
                     grid_stride=False, cluster_dim=cluster_blocks if cluster_blocks > 1 else None,
                     module="unique",
                     module_options={"fast_math": True, "enable_backward": False, "block_dim": max_threads})


def frame_kernel(layout: BlockLayout, device: wp.Device) -> wp.Kernel:
    """The frame kernel for `layout` on `device`, its own module (compiled when first loaded). On CUDA the cluster
    size is compiled in, and the block's threads are its launch bounds: the registers a thread may take (the
    kernel spills at 64, the cap for 1,024 threads; fewer threads a block leave it more). The CPU runs any layout
    with one kernel. No grid-stride loop: each thread is one lane of one world for the whole frame (a thread
    looping over several would meet the barriers out of step)."""
    if device.is_cuda:
        return _frame_kernel(layout.cluster_blocks, layout.threads)
    return _frame_kernel(1, MAX_BLOCK_THREADS)
