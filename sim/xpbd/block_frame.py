"""A whole frame of the XPBD cloth solver in one kernel launch: world w is thread block w, whose threads share the
world's vertices (and triangles) and meet at a block barrier between the steps that read what others wrote.

A small cloth is launch-bound in the sweep kernels (`sim.xpbd.solver`: ~600 graph nodes a frame at 8 x 75, ~2 µs
each on an H100, whatever the mesh size); here a sweep costs one barrier. Each step is the sweep path's per-vertex
(per-triangle) function, in the same order, on the same arrays: the prediction (`kernels.predict_vertex`,
`body_contact.predict_near_body`), the self-contact search (`self_contact.face_bounds`, an exhaustive search of the
world's triangles whose boxes overlap the vertex's box: the candidates the BVH query finds, listed in the same
sorted order, `self_contact.sort_face_list`; the triangles are tested a chunk of CHUNK_FACES consecutive ids at
a time, a chunk's box first), the Jacobi sweeps (`contact_sweep.swept_vertex`,
`kernels.distance_correction`) and the substep's end (`body_contact.finish_vertex`, `kernels.store_state`). So with
one lane a vertex the arithmetic is the sweep path's (bit for bit on the CPU, where a block is one thread).
The sweeps' positions live in shared memory where the world fits (SHARED_VERTICES; a sweep's gather is a chain of
dependent loads, each ~30 cycles there against several hundred from L2, where the last sweep's writes went); a
larger world's stay in global memory (a block's writes before a barrier are visible to the block after it). The
functions are unchanged either way: they index the Jacobi sweep's x_in and x_out, which then view shared memory.
The harmonic projection (a reduction over the world) is not done here: a high-res run keeps the sweep kernels.
"""
from __future__ import annotations

import warp as wp

# Fast math on CUDA, as in sim.xpbd.kernels (why it is safe there holds here: no transcendental function). No
# adjoint: nothing differentiates a frame, and the kernel's backward pass would double its compile time.
wp.set_module_options({"fast_math": True, "enable_backward": False})

from sim.xpbd.body_contact import Capsules, finish_vertex, predict_near_body
from sim.xpbd.contact_sweep import swept_vertex
from sim.xpbd.kernels import (DistanceConstraints, JacobiSweep, PinDrive, Substep, distance_correction,
                              predict_vertex, store_state)
from sim.xpbd.self_contact import (SelfContacts, end_search, face_bounds, list_candidate, search_box,
                                   sort_face_list, start_search)

# The most threads a block (one world) runs: the kernel is compiled for it (__launch_bounds__, which caps its
# registers at 64 a thread), and a block of fewer threads takes several vertices a thread.
MAX_BLOCK_THREADS = 1024
# The most vertices a world may have to be stepped in one block (a few per thread); larger cloths keep the sweep
# kernels, which spread a sweep over the whole GPU.
MAX_BLOCK_VERTICES = 4096
# The most vertices a world may have for its sweeps' positions to live in shared memory on CUDA: two buffers of
# vec3, 36 KB (within the 48 KB a block may declare statically, beside Warp's own 1 KB).
SHARED_VERTICES = 1536
# The search tests the box of this many consecutive triangles before testing theirs: a mesh's ids are close in
# space, so a vertex's box meets few chunks (the 3.7k-vertex pants hanging: 225 chunks of its 7,176 triangles, a
# vertex's box meeting ~10 and at most 26, so ~540 boxes tested instead of 7,176; the paper's 757-vertex pants: ~6
# of 46). A chunk's box holds its triangles' boxes (min and max are exact), so every triangle whose box meets the
# vertex's is still tested: the candidates are the same.
CHUNK_FACES = 32


@wp.struct
class FaceChunks:
    """The box of each chunk of CHUNK_FACES consecutive triangles of a world (the last may hold fewer), world after
    world: world w's chunks are rows w C .. w C + C - 1."""
    lower: wp.array(dtype=wp.vec3)
    upper: wp.array(dtype=wp.vec3)
    per_world: int                    # C


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __syncthreads();
#else
    WP_TILE_SYNC();
#endif
""")
def block_barrier():
    """Every thread of the block waits here until all have arrived, and sees their writes before it. On the CPU
    a block is one thread (nothing to wait for), or with warp.config.enable_cpu_blocks as many fibers, which take
    turns at the barriers (what the tests use to check the barriers without a GPU)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __shared__ wp::vec3 buffer[2 * {SHARED_VERTICES}];
    if (in_shared) {
        wp::array_t<wp::vec3> view = fallback;
        view.data = buffer + half * {SHARED_VERTICES} - first;
        return view;
    }
#endif
    return fallback;
""".replace("{SHARED_VERTICES}", str(SHARED_VERTICES)))
def shared_positions(fallback: wp.array(dtype=wp.vec3), half: int, first: int,
                     in_shared: int) -> wp.array(dtype=wp.vec3):
    """With in_shared (CUDA), a view of half `half` (0 or 1) of the block's shared buffer indexed by the world's
    vertex ids (`first`, the world's first, is its first entry); else `fallback`, the global buffer."""
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


@wp.func
def boxes_overlap(lower: wp.vec3, upper: wp.vec3, box_lower: wp.vec3, box_upper: wp.vec3) -> bool:
    """The BVH query's box test (Warp's intersect_aabb_aabb: closed boxes), so the search finds its hits."""
    return not (lower[0] > box_upper[0] or lower[1] > box_upper[1] or lower[2] > box_upper[2]
                or upper[0] < box_lower[0] or upper[1] < box_lower[1] or upper[2] < box_lower[2])


@wp.func
def chunk_bounds(c: int, world: int, sc: SelfContacts, chunks: FaceChunks):
    """The box of chunk c (a row of `chunks`) of `world`, from its triangles' face_bounds boxes."""
    start = world * sc.world_faces + (c - world * chunks.per_world) * CHUNK_FACES
    end = wp.min(start + CHUNK_FACES, (world + 1) * sc.world_faces)
    lower = sc.face_lower[start]
    upper = sc.face_upper[start]
    for t in range(start + 1, end):
        lower = wp.min(lower, sc.face_lower[t])
        upper = wp.max(upper, sc.face_upper[t])
    chunks.lower[c] = lower
    chunks.upper[c] = upper


@wp.func
def search_own_world(i: int, sub: Substep, sc: SelfContacts, chunks: FaceChunks, overflow_flag: int):
    """find_self_contacts of vertex i, every triangle of its world whose box meets the vertex's listed (the BVH
    path's candidates are those same triangles: contact_side rejects other worlds'), the chunks' boxes tested
    first."""
    search = start_search(i, sub, sc)
    if sub.inv_mass[i] > 0.0:
        lower, upper = search_box(i, sub, sc)
        world = i // sc.world_vertices
        for c in range(world * chunks.per_world, (world + 1) * chunks.per_world):
            if boxes_overlap(lower, upper, chunks.lower[c], chunks.upper[c]):
                start = world * sc.world_faces + (c - world * chunks.per_world) * CHUNK_FACES
                for t in range(start, wp.min(start + CHUNK_FACES, search.own_faces[1])):
                    if boxes_overlap(lower, upper, sc.face_lower[t], sc.face_upper[t]):
                        search = list_candidate(i, t, search, sub, sc, overflow_flag)
    end_search(i, search, sc)


# No grid-stride loop: each thread is one lane of one world's block for the whole frame (a thread looping over
# several would meet the barriers out of step).
@wp.kernel(launch_bounds=MAX_BLOCK_THREADS, grid_stride=False)
def step_frame(substeps: wp.array(dtype=Substep), pins: PinDrive, constraints: DistanceConstraints,
               sweeps: wp.array(dtype=JacobiSweep), sc: SelfContacts, chunks: FaceChunks, capsules: Capsules,
               body_collision: int, self_collision: int, in_shared: int):
    """Every substep of a frame for world `world` (launch_tiled over the worlds): the launches of
    ClothSolver._launch_frame without harmonic projection, each a loop of the block's threads over the world's
    vertices or triangles, a barrier after each that others read from. `substeps` and `sweeps` are the structs
    the sweep kernels are launched with, one per substep and per iteration; with in_shared their positions
    ping-pong in shared memory instead of the state's positions and the work array."""
    world, thread = wp.tid()
    threads = wp.block_dim()
    n = substeps[0].world_vertices
    first, last = world * n, (world + 1) * n
    collide = body_collision != 0 or self_collision != 0
    overflow_flag = substeps.shape[0]
    iterations = sweeps.shape[0]
    even = shared_positions(sweeps[0].x_in, 0, first, in_shared)
    odd = shared_positions(sweeps[0].x_out, 1, first, in_shared)
    for s in range(substeps.shape[0]):
        sub = substeps[s]
        for i in range(first + thread, last, threads):
            if body_collision != 0:
                predict_near_body(i, sub, pins, capsules)
            else:
                sub.x[i] = predict_vertex(i, sub, pins)
            even[i] = sub.x[i]   # the first sweep's input (the same array, without in_shared)
        block_barrier()
        if self_collision != 0:
            faces = sc.world_faces
            for t in range(world * faces + thread, (world + 1) * faces, threads):
                face_bounds(t, sub.x, sub.x_prev, sc)
            block_barrier()
            for c in range(world * chunks.per_world + thread, (world + 1) * chunks.per_world, threads):
                chunk_bounds(c, world, sc, chunks)
            block_barrier()
            for i in range(first + thread, last, threads):
                search_own_world(i, sub, sc, chunks, overflow_flag)
            block_barrier()
            for t in range(world * faces + thread, (world + 1) * faces, threads):
                sort_face_list(t, sc)
            block_barrier()
        for k in range(iterations):
            sweep = in_buffers(sweeps[k], k, even, odd)
            for i in range(first + thread, last, threads):
                if collide:
                    sweep.x_out[i] = swept_vertex(i, 0, 1, sub, constraints, sweep, sc, capsules)
                else:
                    sweep.x_out[i] = sweep.x_in[i] + distance_correction(i, sweep.x_in[i], sub, constraints, sweep,
                                                                         0, 1)
            block_barrier()
        # A vertex's end of the substep and next prediction read and write its own entries only: no barrier.
        solved = in_buffers(sweeps[iterations - 1], iterations - 1, even, odd).x_out
        for i in range(first + thread, last, threads):
            if collide:
                finish_vertex(i, sub, solved, capsules, 1)
            else:
                store_state(i, solved[i], sub)
