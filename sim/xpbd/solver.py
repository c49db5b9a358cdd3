"""Host side of the XPBD cloth solver: the device layout of the constraints and frame stepping (Warp, CPU or CUDA).

A frame of length dt is split into `substeps`; each substep predicts positions, runs `iterations` Jacobi sweeps
over the distance constraints (and, for a high-res run, projects onto the harmonic constraint after each sweep),
and derives velocities. With body or self-collision on, the same steps use the kernels of `sim.xpbd.body_contact`
and `sim.xpbd.contact_sweep` (contacts fused into them) plus, for self-collision, a broad phase once per substep
(`sim.xpbd.self_contact`). A cloth that fits a thread block (the low-res run) may instead step the whole frame in
one launch, a block per world (`sim.xpbd.block_frame`: the same functions; frame_kernel_of). On CUDA the whole
frame is captured once as a graph and replayed; per-frame inputs (pin targets, harmonic targets, capsules) live in
device arrays that are overwritten before each replay. The graph holds the state's arrays too, which is why the
solver makes the state it steps.

A solver steps `worlds` independent copies of the cloth at once (B sequences of one garment, each with its own
pins, body motion and harmonic targets): the kernels run over the worlds' vertices one after the other (see
`sim.xpbd.kernels`), so a batch costs the launches of one cloth. Arrays of every world are world-major: the state
holds (B V, 3) positions, and a per-world input is (B, ...) (or, with one world, also without the batch axis).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from geometry.harmonics import lumped_mass
from geometry.mesh import unique_edges
from sim.solver import Solver, UnstableSimulation
from sim.xpbd import (block_frame, body_contact, cluster_exchange, contact_sweep, kernels, self_contact,
                      world_search)
from sim.xpbd.constraints import HarmonicConstraint, cloth_constraints, vertex_incidence
from sim.xpbd.model import ClothModel


@dataclass(frozen=True, eq=False)
class ClothState:
    """What a frame advances: the positions and velocities of the vertices of every world, (B V,) vec3 device
    arrays, world after world. Made by ClothSolver (`solver.state`); stepping updates the arrays in place, so they
    are the same every frame."""
    positions: wp.array
    velocities: wp.array
    worlds: int = 1

    def read_positions(self) -> np.ndarray:
        """(B V, 3) float64 copy on the host (world w's vertices are rows w V .. w V + V - 1)."""
        return self.positions.numpy().astype(np.float64)

    def read_world_positions(self) -> np.ndarray:
        """(B, V, 3) float32 copy on the host. On the CPU device `numpy()` is a view of the live array, which the
        next step would overwrite, so it is copied; on CUDA it is a copy already (a second one cost ~2 ms a frame of
        64 paper-pants worlds, 9 MB)."""
        host = self.positions.numpy().reshape(self.worlds, -1, 3)
        return host.copy() if self.positions.device.is_cpu else host

    def read_velocities(self) -> np.ndarray:
        return self.velocities.numpy().astype(np.float64)

    def write_velocities(self, velocities: np.ndarray) -> None:
        self.velocities.assign(np.asarray(velocities, dtype=np.float32))


@dataclass(frozen=True)
class FrameInputs:
    """The kinematic inputs of a frame (Newton's Control), at its end; the solver interpolates each linearly across
    the substeps from the previous frame's values. Each is needed exactly when the model has what it drives (pinned
    vertices, a harmonic constraint, body collision). Each has a leading world axis (B, ...), optional with one
    world."""
    pin_targets: np.ndarray | None = None      # (B, P, 3) positions of the pinned vertices
    harmonic_target: np.ndarray | None = None  # (B, K, 3) B^T M S x_low, for a run with the harmonic constraint
    capsules: np.ndarray | None = None         # (B, N, 2, 3) capsule end points, with body collision


# Worlds' boxes in the shared self-contact BVH lie this many rest-mesh diagonals apart (self_contact.world_offset):
# far enough that no two worlds' cloths meet unless one strays several garment sizes from the others.
WORLD_SPACING = 8.0

# Self-contact lists start with room for this many entries per vertex and per triangle; a frame that fills one is
# stepped again from its start with room for twice what the fullest list needed (a power of two), up to
# MAX_CONTACT_CAPACITY (then contacts are dropped, with a warning). A solver keeps the room it grew. Contacts pile up
# over frames as a cloth drapes or folds, and each growth costs a frame stepped again and, on CUDA, the graph
# captured again: doubling on every overflow (as before) grew the test sheets' lists 2 -> 16 in 3 growths, growing
# to twice the need in 2.
CONTACT_CAPACITY = 32
MAX_CONTACT_CAPACITY = 512

# Threads per vertex in a CUDA Jacobi sweep (kernels.lane_sum_vec3): a sweep of few vertices is latency-bound, and lanes
# shorten each thread's walk; a sweep of many is bound by throughput, which lanes only spend on index arithmetic.
# On an H100 (docs/performance.md): one 3.7k-vertex cloth is fastest with 8 lanes, one 14.5k-vertex cloth with 4,
# 128 worlds of 3.7k (0.47 M vertices) with 1. So: about SWEEP_THREADS threads a sweep, 1 to 8 lanes. The CPU runs
# one thread per vertex (its kernels run serially: lanes would only add loop overhead).
SWEEP_THREADS = 65536
MAX_SWEEP_LANES = 8


def cuda_sweep_lanes(vertices: int) -> int:
    """The default lanes for a CUDA sweep over `vertices` (all worlds'): the largest power of two of at most
    MAX_SWEEP_LANES with vertices * lanes <= SWEEP_THREADS, and at least 1."""
    lanes = 1
    while 2 * lanes <= MAX_SWEEP_LANES and 2 * lanes * vertices <= SWEEP_THREADS:
        lanes *= 2
    return lanes


def frame_kernel_of(model: ClothModel, device: wp.Device, worlds: int = 1) -> str:
    """"block" where the model's frame is stepped in one launch, else "sweeps" (frame_kernel_for)."""
    return frame_kernel_for(model.settings.frame_kernel, len(model.rest_vertices), model.harmonic is not None,
                            device, worlds)


def frame_kernel_for(wanted: str, vertices: int, harmonic: bool, device: wp.Device, worlds: int = 1) -> str:
    """"block" where settings.frame_kernel `wanted` steps a frame of `worlds` cloths of `vertices` (with the
    harmonic constraint or not) on `device` in one launch, else "sweeps": "block" where the cloth fits a block (no
    harmonic constraint, at most block_frame.MAX_BLOCK_VERTICES vertices), "auto" where it was measured faster than
    the sweeps: on a GPU with thread block clusters (compute capability 9.0), worlds in a cluster's shared memory
    (block_frame.SHARED_VERTICES) few enough that each takes a whole cluster of MAX_CLUSTER_BLOCKS blocks at once
    (its default layout). One block a world, a world in global memory, or many worlds in smaller clusters were
    slower than the sweeps wherever measured (an H200: 1.16x the sweeps for one paper pants, 1.02x for 8, 0.60-0.87x
    for 32 to 256 in clusters of 4 to 1 blocks), and the CPU's launches cost little next to a block's exhaustive
    self-contact search (docs/performance.md, "One launch a frame"). A function of these alone, so that a caller may
    ask it without building the model (the trade-off stage: which kernels to time)."""
    fits = not harmonic and vertices <= block_frame.MAX_BLOCK_VERTICES
    whole_clusters = (block_frame.clusters_serve(device, vertices) and block_frame.default_layout(
        vertices, worlds, device).cluster_blocks == block_frame.MAX_CLUSTER_BLOCKS)
    if fits and (wanted == "block" or (wanted == "auto" and whole_clusters)):
        return "block"
    return "sweeps"


def per_entry_multipliers(frame_kernel: str, layout: block_frame.BlockLayout | None) -> bool:
    """Whether the sweeps keep a multiplier per entry of the vertices' lists (kernels.distance_correction): in a
    cluster of blocks, where no thread may read what another block wrote in the same sweep. Elsewhere one per
    constraint (half the multipliers' memory traffic, which a batched sweep is bound by)."""
    return frame_kernel == "block" and layout.cluster_blocks > 1


# How far beyond the thickness (in mean rest edge lengths) contacts are prepared at the prediction, for the motion
# of the iterations: a vertex watches the capsules within one edge (the constraints may pull it that far: a
# watched capsule is swept, so a vertex pulled across a thin limb stays on its side), and self-contact pairs
# within a quarter edge become candidates (each costs a little in every iteration).
BODY_MARGIN = 1.0
SELF_MARGIN = 0.25


class ClothSolver(Solver[ClothModel, ClothState, FrameInputs]):
    """Steps a cloth model frame by frame on one Warp device.

    `step(state, inputs)` advances `solver.state`, the one state the solver makes: a CUDA graph replays its launches
    with the device arrays it was captured with, and the solver also keeps memory of the trajectory (the previous
    frame's inputs, from which a frame interpolates, and the sides of the self-contacts), so a second trajectory
    needs a second solver (or a second world of one). `worlds` copies of the model are stepped together, each with
    its own inputs. The state starts at `initial_positions` ((V, 3) for every world, or (B, V, 3); default: the
    rest positions) with zero velocities; the pins start where the state has them, and `initial_inputs` gives the
    other inputs at frame 0: the harmonic target (B, K, 3) of a model with the harmonic constraint (default 0) and,
    with body collision, the capsules' end points (B, N, 2, 3). `sweep_lanes` threads share a vertex in each Jacobi
    sweep (default: cuda_sweep_lanes on CUDA, 1 on the CPU; the sums' order, not the physics, depends on it);
    `contact_capacity` is the self-contact lists' first room per vertex (they grow when a frame fills them).
    `frame_kernel` is "block" where a frame is one launch of a block (or a cluster of blocks) per world
    (sim.xpbd.block_frame; the settings' `frame_kernel` and the cloth decide: frame_kernel_of), else "sweeps";
    `block_layout` spreads a world over threads there (block_frame.BlockLayout; default: block_frame.default_layout,
    one thread on the CPU, where more take turns as fibers with warp.config.enable_cpu_blocks), its sweeps' positions
    in shared memory where the world fits (`block_shared`, CUDA).
    """

    def __init__(self, model: ClothModel, device: str, worlds: int = 1, initial_inputs: FrameInputs = FrameInputs(),
                 initial_positions: np.ndarray | None = None, contact_capacity: int = CONTACT_CAPACITY,
                 sweep_lanes: int | None = None, block_layout: block_frame.BlockLayout | None = None):
        if not (isinstance(worlds, int) and worlds >= 1):
            raise ValueError(f"worlds must be a positive integer, got {worlds!r}")
        if initial_inputs.pin_targets is not None:
            raise ValueError("the pins start where initial_positions put them: initial_inputs takes no pin_targets")
        self.model = model
        rest_vertices, faces, pinned = model.rest_vertices, model.faces, model.pinned
        self.device = wp.get_device(device)
        if sweep_lanes is None:
            sweep_lanes = cuda_sweep_lanes(worlds * len(rest_vertices)) if self.device.is_cuda else 1
        if sweep_lanes not in ((1, 2, 4, 8, 16) if self.device.is_cuda else (1,)):
            raise ValueError(f"sweep_lanes must be 1, 2, 4, 8 or 16 on CUDA (threads of a warp per vertex) and 1 on "
                             f"the CPU, got {sweep_lanes!r}")
        self.sweep_lanes = sweep_lanes
        self.frame_kernel = frame_kernel_of(model, self.device, worlds)
        self.worlds = worlds
        self.world_vertices = n = len(rest_vertices)
        if self.frame_kernel == "block":
            self._choose_block_layout(block_layout)
        elif block_layout is not None:
            raise ValueError("block_layout applies to a frame stepped in one launch (frame_kernel 'block') only")
        else:
            self.block_layout, self.block_shared = None, False
        s = model.settings
        h = s.dt / s.substeps
        mass = s.density * lumped_mass(rest_vertices, faces)
        inv_mass = 1.0 / mass
        inv_mass[pinned] = 0.0
        x0 = rest_vertices if initial_positions is None else np.asarray(initial_positions, dtype=np.float64)
        if x0.shape == (n, 3):
            x0 = np.broadcast_to(x0, (worlds, n, 3))
        x0 = self._per_world(x0, (n, 3), "initial_positions")

        arr = self._array
        self.state = ClothState(positions=arr(x0, wp.vec3), velocities=self._zeros(worlds * n, wp.vec3),
                                worlds=worlds)
        x_prev = arr(x0, wp.vec3)
        x_work = arr(x0, wp.vec3)
        # Per world one flag per substep (blow-up) and a last one for overflowing self-contact lists (the room the
        # fullest list needed).
        self.flags = self._zeros((worlds, s.substeps + 1), int)
        self._substeps = self._substep_structs(h, x_prev, arr(np.tile(inv_mass, worlds), float))
        self.pins = self._pin_drive(pinned, x0, n)
        self.n_pins = len(pinned)
        self.constraints, self.n_constraints = self._distance_constraints(rest_vertices, faces, h, n, inv_mass)
        per_entry = per_entry_multipliers(self.frame_kernel, self.block_layout)
        total = worlds * (self.constraints.entries.shape[0] if per_entry else self.n_constraints)
        lambdas = (self._zeros(total, float), self._zeros(total, float))
        self._sweeps = self._jacobi_sweeps((self.state.positions, x_work), lambdas, per_entry)
        self.harmonic_projection = (None if model.harmonic is None
                                    else self._harmonic_projection(model.harmonic, initial_inputs.harmonic_target, n))

        edges = unique_edges(faces)
        mean_edge = float(np.linalg.norm(rest_vertices[edges[:, 0]] - rest_vertices[edges[:, 1]], axis=1).mean())
        self.capsules = self._capsules(initial_inputs.capsules, s.collision_thickness + BODY_MARGIN * mean_edge, n)
        diagonal = float(np.linalg.norm(np.ptp(rest_vertices, axis=0)))
        self.contacts = self._self_contacts(faces, s.self_thickness + SELF_MARGIN * mean_edge, n,
                                            WORLD_SPACING * max(diagonal, mean_edge), contact_capacity)
        if self.frame_kernel == "block":
            self._block_frame_arrays()
        self.frames_stepped_again = 0      # frames whose self-contact lists overflowed (the log says how many)
        # What a frame that overflows the contact lists restarts from (copied at the start of every frame).
        self._frame_start = None if not s.self_collision else ClothState(
            arr(x0, wp.vec3), self._zeros(worlds * n, wp.vec3), worlds)
        self._graph = None

    def _choose_block_layout(self, layout: block_frame.BlockLayout | None) -> None:
        """The threads of a world in the block frame (`layout`, or the default) and whether its sweeps' positions
        live in shared memory (CUDA, where the world fits; on the CPU a block is one thread)."""
        self.block_shared = self.device.is_cuda and self.world_vertices <= block_frame.SHARED_VERTICES
        if layout is None:
            layout = block_frame.default_layout(self.world_vertices, self.worlds, self.device)
        self.block_layout = block_frame.checked_layout(layout, self.device, self.world_vertices)

    def _block_frame_arrays(self) -> None:
        """The block frame's search arrays (world_search.WorldSearch: its chunks' boxes, its vertices' previous list
        lengths, its queue of candidates), and the structs of every substep and sweep as device arrays (the block
        kernel reads them in turn, the same structs the sweep kernels are launched with)."""
        search = world_search.WorldSearch()
        search.per_world = math.ceil(len(self.model.faces) / world_search.CHUNK_FACES)
        collide = self.model.settings.self_collision
        rows = self.worlds * search.per_world if collide else 1
        search.lower, search.upper = self._zeros(rows, wp.vec3), self._zeros(rows, wp.vec3)
        search.previous_count = self._zeros(self.worlds * self.world_vertices if collide else 1, int)
        # A queued candidate is t V + i in one int32: a world too large for that has no queue (its pairs test
        # their own hits).
        fits = collide and len(self.model.faces) * self.world_vertices < 2**31
        search.queue_room = world_search.QUEUE_PER_VERTEX * self.world_vertices if fits else 0
        search.queue = self._zeros(max(self.worlds * search.queue_room, 1), int)
        search.queue_count = self._zeros(self.worlds, int)
        self._world_search = search
        exchange = cluster_exchange.ClusterExchange()
        exchange.readers = self._zeros(self.worlds * self.world_vertices, int)
        blocks = self.worlds * self.block_layout.cluster_blocks
        exchange.incoming, exchange.senders, exchange.receivers = (self._zeros(blocks, int) for _ in range(3))
        exchange.per_block = cluster_exchange.vertices_a_block(self.world_vertices, self.block_layout.cluster_blocks)
        self._cluster_exchange = exchange
        self._substep_array = wp.array(self._substeps, dtype=kernels.Substep, device=self.device)
        self._sweep_array = wp.array(self._sweeps, dtype=kernels.JacobiSweep, device=self.device)

    def launch_summary(self) -> str:
        """How a frame is launched, in words (benches and logs): the sweeps' lanes, or the block's threads."""
        if self.frame_kernel == "sweeps":
            return f"sweeps, {self.sweep_lanes} lane(s) a vertex"
        layout = self.block_layout
        where = f"a cluster of {layout.cluster_blocks} blocks" if layout.cluster_blocks > 1 else "a block"
        return (f"{where} a world, {layout.threads} thread(s) a block, {layout.lanes} lane(s) a vertex"
                + (", shared memory" if self.block_shared else ""))

    def _per_world(self, value, shape: tuple[int, ...], name: str) -> np.ndarray:
        """`value` of shape (B, *shape) (or `shape` with one world) as rows world after world, (B shape[0], ...)."""
        value = np.asarray(value, dtype=np.float64)
        if self.worlds == 1 and value.shape == shape:
            value = value[None]
        if value.shape != (self.worlds, *shape):
            raise ValueError(f"{name} must have shape {(self.worlds, *shape)} (one row per world); got {value.shape}")
        return value.reshape(self.worlds * shape[0], *shape[1:])

    def _tile_ids(self, ids: np.ndarray, n: int) -> np.ndarray:
        """Vertex ids of one world (any shape) as those of every world, world after world along the first axis."""
        ids = np.asarray(ids, dtype=np.int64)
        offsets = (np.arange(self.worlds) * n).reshape(-1, *([1] * ids.ndim))
        return (ids[None] + offsets).reshape(self.worlds * len(ids), *ids.shape[1:])

    def _tile_csr(self, offsets: np.ndarray, values: np.ndarray, value_step: int) -> tuple[np.ndarray, np.ndarray]:
        """One world's per-vertex lists (CSR offsets (n+1,), values) as every world's, world after world, values
        shifted by `value_step` a world: what the lists of the tiled ids would be (each world's entries keep their
        order), without sorting all worlds' entries (~0.6 s of a 64-world paper-pants batch's construction)."""
        worlds = np.arange(self.worlds)[:, None]
        tiled_offsets = np.append((offsets[:-1][None] + worlds * len(values)).ravel(), self.worlds * len(values))
        return tiled_offsets, (values[None] + worlds * value_step).ravel()

    def _array(self, data: np.ndarray, dtype) -> wp.array:
        np_dtype = np.int32 if dtype in (int, wp.vec2i, wp.vec3i) else np.float32
        return wp.array(np.ascontiguousarray(data, dtype=np_dtype), dtype=dtype, device=self.device)

    def _zeros(self, shape, dtype) -> wp.array:
        """Zeros made on the device (a memset there), not uploaded: a 64-world paper-pants batch's contact lists
        alone are ~0.5 GB."""
        return wp.zeros(shape, dtype=dtype, device=self.device)

    def _substep_structs(self, h: float, x_prev: wp.array, inv_mass: wp.array) -> list[kernels.Substep]:
        """The kernels' view of each substep of a frame: the state's arrays, the integration constants and the
        substep's place in the frame."""
        s = self.model.settings
        substeps = []
        for index in range(s.substeps):
            sub = kernels.Substep()
            sub.x, sub.v, sub.x_prev, sub.inv_mass = self.state.positions, self.state.velocities, x_prev, inv_mass
            sub.gravity = wp.vec3(*s.gravity)
            sub.h, sub.inv_h, sub.damping_factor = h, 1.0 / h, math.exp(-s.damping * h)
            sub.max_speed = s.max_speed
            sub.f0, sub.f1 = index / s.substeps, (index + 1) / s.substeps
            sub.index = index
            sub.world_vertices = self.world_vertices
            sub.flags = self.flags
            substeps.append(sub)
        return substeps

    def _pin_drive(self, pinned: np.ndarray, x0: np.ndarray, n: int) -> kernels.PinDrive:
        """Each pinned vertex's slot (world w's pins take slots w P .. w P + P - 1), its targets starting where the
        vertex starts (one dummy slot without pins)."""
        pins = kernels.PinDrive()
        slot = np.full(self.worlds * n, -1, dtype=np.int32)
        every_pin = self._tile_ids(pinned, n)
        slot[every_pin] = np.arange(len(every_pin), dtype=np.int32)
        pins.slot = self._array(slot, int)
        start = x0[every_pin] if len(pinned) else np.zeros((1, 3))
        pins.start, pins.end = self._array(start, wp.vec3), self._array(start, wp.vec3)
        return pins

    def _distance_constraints(self, rest_vertices: np.ndarray, faces: np.ndarray, h: float, n: int,
                              inv_mass: np.ndarray) -> tuple[kernels.DistanceConstraints, int]:
        """The cloth's constraints listed per vertex, one world's (kernels.DistanceConstraints), and their count."""
        s = self.model.settings
        con = cloth_constraints(rest_vertices, faces, s)
        offsets, neighbor, constraint = vertex_incidence(con.pairs, n)
        count = np.diff(offsets)
        arr = self._array
        dc = kernels.DistanceConstraints()
        dc.offsets = arr(offsets, int)
        compliant = con.compliance[constraint] != 0
        dc.entries = arr(np.stack([neighbor, np.where(compliant, -1 - constraint, constraint)], axis=1), wp.vec2i)
        scale = s.relaxation / np.maximum(count[con.pairs[:, 0]], count[con.pairs[:, 1]])
        dc.params = arr(np.stack([con.rest_min, con.rest_max, con.compliance / (h * h), scale], axis=1), wp.vec4)
        dc.inv_mass = arr(inv_mass, float)
        return dc, len(con.pairs)

    def _jacobi_sweeps(self, buffers: tuple[wp.array, wp.array],
                       lambdas: tuple[wp.array, wp.array], per_entry: bool) -> list[kernels.JacobiSweep]:
        """The buffers of each iteration of a substep: positions ping-pong between the state's positions and a work
        array, multipliers between two arrays, and the first iteration starts from zero multipliers. The last
        iteration's x_out holds the solved positions."""
        sweeps = []
        for it in range(self.model.settings.iterations):
            sweep = kernels.JacobiSweep()
            sweep.x_in, sweep.x_out = buffers[it % 2], buffers[(it + 1) % 2]
            sweep.lambda_in, sweep.lambda_out = lambdas[it % 2], lambdas[(it + 1) % 2]
            sweep.lambda_carry = 0.0 if it == 0 else 1.0
            sweep.lambda_per_entry = int(per_entry)
            sweeps.append(sweep)
        return sweeps

    def _harmonic_projection(self, harmonic: HarmonicConstraint, target: np.ndarray | None,
                             n: int) -> kernels.HarmonicProjection:
        """The projection's bases and reduction buffers (in chunks of 64 rows), targets at frame 0."""
        hp = kernels.HarmonicProjection()
        n_modes = harmonic.mass_basis.shape[1]
        hp.rows_per_chunk = 64
        n_chunks = math.ceil(n / hp.rows_per_chunk)
        hp.mass_basis = wp.array(harmonic.mass_basis.astype(np.float32), dtype=float, device=self.device)
        hp.correction_basis_t = wp.array(np.ascontiguousarray(harmonic.correction_basis.T, dtype=np.float32),
                                         dtype=float, device=self.device)
        hp.partial = wp.zeros((self.worlds, n_chunks, n_modes), dtype=wp.vec3, device=self.device)
        hp.residual = wp.zeros((self.worlds, n_modes), dtype=wp.vec3, device=self.device)
        target = np.zeros((self.worlds, n_modes, 3)) if target is None else target
        target = self._per_world(target, (n_modes, 3), "harmonic_target").reshape(self.worlds, n_modes, 3)
        hp.target_start, hp.target_end = self._array(target, wp.vec3), self._array(target, wp.vec3)
        return hp

    def _capsules(self, ends, reach: float, n: int) -> body_contact.Capsules:
        """The capsules at frame 0 (`ends`) and per-vertex body-contact state (with body collision off: no capsules,
        so the kernels' capsule loops are empty)."""
        s = self.model.settings
        capsules = body_contact.Capsules()
        capsules.near = self._zeros(self.worlds * n, int)
        capsules.push = self._zeros(self.worlds * n, float)
        capsules.per_world = 0
        if not s.body_collision:
            if ends is not None:
                raise ValueError("capsules were given but settings.body_collision is off")
            return capsules
        if ends is None:
            raise ValueError("body_collision needs capsules at frame 0: initial_inputs.capsules (B, N, 2, 3)")
        ends = np.asarray(ends, dtype=np.float64)
        radii = self.model.capsule_radii
        if ends.ndim == 3 and self.worlds == 1:
            ends = ends[None]
        if ends.ndim != 4 or ends.shape[0] != self.worlds or ends.shape[2:] != (2, 3) or radii.shape != ends.shape[1:3]:
            raise ValueError(f"capsules must be (B, N, 2, 3) with B = {self.worlds} worlds and capsule_radii (N, 2); "
                             f"got {ends.shape} and {radii.shape}")
        ends = ends.reshape(-1, 2, 3)
        length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
        radii = np.tile(radii, (self.worlds, 1))
        if (length <= np.abs(radii[:, 0] - radii[:, 1])).any():
            raise ValueError("each capsule segment must be longer than the difference of its end radii")
        capsules.start = self._array(ends, wp.vec3)
        capsules.end = self._array(ends, wp.vec3)
        capsules.radius = self._array(radii, float)
        capsules.shapes = wp.empty(len(radii), dtype=body_contact.CapsuleShape, device=self.device)
        capsules.per_world = len(radii) // self.worlds
        capsules.thickness = s.collision_thickness
        capsules.reach = reach
        capsules.friction = s.friction
        return capsules

    def _self_contacts(self, faces: np.ndarray, reach: float, n: int, spacing: float,
                       capacity: int) -> self_contact.SelfContacts:
        """Mesh, broad phase and contact lists for self-collision (with it off: empty lists only), every world's.

        The triangle BVH is built once over the initial boxes with the same (SAH) builder on every device, so CPU
        and CUDA traverse identical trees; each substep only refits it. Worlds share it, their boxes `spacing`
        apart on a lattice (self_contact.world_offset)."""
        s = self.model.settings
        total = self.worlds * n
        sc = self_contact.SelfContacts()
        sc.vertex_count = self._zeros(total, int)
        sc.corner_count = self._zeros(total, int)
        if not s.self_collision:  # no lists and no triangles around any vertex: the iterations find no contact
            sc.face_offsets = self._zeros(total + 1, int)
            return sc
        edge_offsets, neighbors, _ = vertex_incidence(unique_edges(faces), n)
        if np.diff(edge_offsets).max() > self_contact.MAX_VALENCE:
            raise ValueError(f"self-collision handles vertices of up to {self_contact.MAX_VALENCE} neighbours; this "
                             f"mesh has one with {np.diff(edge_offsets).max()}")
        arr = self._array
        every_face = self._tile_ids(faces, n)
        n_faces = len(every_face)
        sc.faces = arr(every_face, wp.vec3i)
        order = np.argsort(faces.ravel(), kind="stable")
        face_offsets = np.concatenate([[0], np.cumsum(np.bincount(faces.ravel(), minlength=n))])
        face_offsets, vertex_faces = self._tile_csr(face_offsets, np.repeat(np.arange(len(faces)), 3)[order],
                                                    len(faces))
        sc.face_offsets, sc.vertex_faces = arr(face_offsets, int), arr(vertex_faces, int)
        edge_offsets, neighbors = self._tile_csr(edge_offsets, neighbors, n)
        sc.edge_offsets, sc.vertex_neighbors = arr(edge_offsets, int), arr(neighbors, int)
        sc.face_lower = self._zeros(n_faces, wp.vec3)
        sc.face_upper = self._zeros(n_faces, wp.vec3)
        self._size_contact_lists(sc, capacity, total)
        sc.face_count = self._zeros(n_faces, int)
        sc.thickness = s.self_thickness
        sc.reach = reach
        sc.world_vertices, sc.world_faces = n, len(faces)
        sc.lattice = math.ceil(self.worlds ** (1 / 3) - 1e-9)
        sc.spacing = spacing
        if self.frame_kernel == "sweeps":   # the block frame searches its world's triangles without a tree
            x = self.state.positions
            wp.launch(self_contact.contact_bounds, dim=n_faces, device=self.device, inputs=[x, x, sc])
            self._face_bvh = wp.Bvh(sc.face_lower, sc.face_upper, constructor="sah")
            sc.face_bvh = self._face_bvh.id
        return sc

    def _size_contact_lists(self, sc: self_contact.SelfContacts, capacity: int, vertices: int) -> None:
        """(Re)allocate the contact lists, empty, with `capacity` entries (zeros made on the device)."""
        sc.vertex_contacts, sc.previous, self._saved_lists = (self._zeros((vertices, capacity), int) for _ in range(3))
        sc.face_contacts = self._zeros((sc.faces.shape[0], capacity), int)
        self._saved_count = self._zeros(vertices, int)

    def _grow_contact_lists(self, needed: int) -> bool:
        """After a frame that overflowed: grow the lists' capacity to twice the `needed` entries (a power of two,
        at most MAX_CONTACT_CAPACITY) and put the state back at the frame's start, so the frame can be stepped
        again; False if they are at MAX_CONTACT_CAPACITY already."""
        sc = self.contacts
        if sc.vertex_contacts.shape[1] >= MAX_CONTACT_CAPACITY:
            return False
        capacity = min(1 << (2 * needed - 1).bit_length(), MAX_CONTACT_CAPACITY)
        self.frames_stepped_again += 1
        saved_lists, saved_count = self._saved_lists, self._saved_count
        self._size_contact_lists(sc, capacity, len(saved_count))
        # The vertices' lists as the frame started (the sides the search keeps), widened on the device rather than
        # through the host (3 uploads of ~1.5 GB for 64 paper-pants worlds at 256 entries). The other lists are
        # written before they are read: `previous` by the search, the saved ones at the frame's start.
        wp.launch(self_contact.widen_lists, dim=saved_lists.shape, device=self.device,
                  inputs=[saved_lists, sc.vertex_contacts])
        wp.copy(sc.vertex_count, saved_count)
        wp.copy(self.state.positions, self._frame_start.positions)
        wp.copy(self.state.velocities, self._frame_start.velocities)
        self._graph = None   # the graph holds the old lists
        return True

    def step(self, state: ClothState, inputs: FrameInputs = FrameInputs()) -> None:
        """Advance `state` (which must be `self.state`) one frame. Raises UnstableSimulation naming the first bad
        world and substep."""
        if state is not self.state:
            raise ValueError("a ClothSolver steps the state it made (solver.state); a second trajectory needs a "
                             "second solver")
        if self.model.settings.body_collision:
            if inputs.capsules is None:
                raise ValueError("body_collision needs the capsules at the end of the frame")
            per_world = self.capsules.per_world
            capsules = self._per_world(inputs.capsules, (per_world, 2, 3), "capsules")
            self.capsules.start.assign(self.capsules.end)
            self.capsules.end.assign(capsules.astype(np.float32))
        elif inputs.capsules is not None:
            raise ValueError("capsules were given but settings.body_collision is off")
        if self.n_pins:
            targets = self._per_world(inputs.pin_targets, (self.n_pins, 3), "pin_targets")
            self.pins.start.assign(self.pins.end)
            self.pins.end.assign(targets.astype(np.float32))
        if self.harmonic_projection is not None:
            hp = self.harmonic_projection
            n_modes = hp.target_end.shape[1]
            targets = self._per_world(inputs.harmonic_target, (n_modes, 3), "harmonic_target")
            hp.target_start.assign(hp.target_end)
            hp.target_end.assign(targets.reshape(self.worlds, n_modes, 3).astype(np.float32))
        flags = self._run_frame()
        while flags[:, -1].any() and self._grow_contact_lists(int(flags[:, -1].max())):
            flags = self._run_frame()
        if flags[:, -1].any():
            warnings.warn(f"self-contact lists overflowed at their largest capacity ({MAX_CONTACT_CAPACITY}) in "
                          f"world(s) {np.flatnonzero(flags[:, -1]).tolist()}; the extra contacts of this frame were "
                          "dropped", RuntimeWarning, stacklevel=2)
        blown = flags[:, :-1]
        if blown.any():
            world = int(np.flatnonzero(blown.any(axis=1))[0])
            raise UnstableSimulation(world, int(np.argmax(blown[world])), "NaN or speed > max_speed")

    def _run_frame(self) -> np.ndarray:
        """Launch one frame (replaying its graph on CUDA); the flags it raised, (B, substeps + 1)."""
        self.flags.zero_()
        if self.device.is_cuda:
            if self._graph is None:
                # compile before capture: no JIT inside a graph (the block kernel's variant for its block size)
                for module in (kernels, body_contact, self_contact, contact_sweep):
                    wp.load_module(module, device=self.device)
                if self.frame_kernel == "block":
                    wp.load_module(block_frame.frame_kernel(self.block_layout, self.device).module,
                                   device=self.device, block_dim=self.block_layout.threads)
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch_frame()
                self._graph = capture.graph
            wp.capture_launch(self._graph)
        else:
            self._launch_frame()
        return self.flags.numpy()

    def _launch_frame(self) -> None:
        s = self.model.settings
        if s.self_collision:
            for saved, live in ((self._frame_start.positions, self.state.positions),
                                (self._frame_start.velocities, self.state.velocities),
                                (self._saved_lists, self.contacts.vertex_contacts),
                                (self._saved_count, self.contacts.vertex_count)):
                wp.copy(saved, live)
        if self.frame_kernel == "block":
            layout = self.block_layout
            wp.launch_tiled(block_frame.frame_kernel(layout, self.device), dim=[self.worlds * layout.cluster_blocks],
                            block_dim=layout.threads, device=self.device,
                            inputs=[self._substep_array, self.pins, self.constraints, self._sweep_array,
                                    self.contacts, self._world_search, self.capsules, self._cluster_exchange,
                                    int(s.body_collision), int(s.self_collision), int(self.block_shared),
                                    layout.cluster_blocks, layout.lanes])
            return
        n = self.state.positions.shape[0]
        dev = self.device
        collide = s.body_collision or s.self_collision
        for sub in self._substeps:
            if s.body_collision:
                wp.launch(body_contact.capsule_shapes, dim=self.capsules.shapes.shape[0], device=dev,
                          inputs=[self.capsules, sub.f1])
                wp.launch(body_contact.predict_with_body, dim=n, device=dev, inputs=[sub, self.pins, self.capsules])
            else:
                wp.launch(kernels.predict_positions, dim=n, device=dev, inputs=[sub, self.pins])
            if s.self_collision:
                self._launch_broad_phase(sub)
            every_iteration = s.harmonic_every == "iteration"
            for sweep in self._sweeps:
                lanes = self.sweep_lanes
                if collide:
                    wp.launch(contact_sweep.solve_with_collisions, dim=n * lanes, device=dev,
                              inputs=[sub, self.constraints, sweep, self.contacts, self.capsules, lanes])
                else:
                    wp.launch(kernels.solve_distance_constraints, dim=n * lanes, device=dev,
                              inputs=[sub, self.constraints, sweep, lanes])
                if self.harmonic_projection is not None and (every_iteration or sweep is self._sweeps[-1]):
                    self._launch_projection(sweep.x_out, sub.f1)
            solved = self._sweeps[-1].x_out
            # With the body, contacts after the last harmonic projection would break the constraint (friction most):
            # friction first, then the body and the constraint take turns, converging to a shape that meets both.
            rounds = self.harmonic_projection is not None and s.body_collision and s.contact_rounds > 0
            if rounds:
                wp.launch(body_contact.body_friction, dim=n, device=dev, inputs=[sub, solved, self.capsules])
                last = sub is self._substeps[-1]
                for _ in range(s.contact_rounds + (s.frame_end_rounds if last else 0)):
                    wp.launch(body_contact.clear_of_body, dim=n, device=dev, inputs=[sub, solved, self.capsules])
                    self._launch_projection(solved, sub.f1)
            if collide:
                wp.launch(body_contact.finish_substep, dim=n, device=dev,
                          inputs=[sub, solved, self.capsules, int(not rounds)])
            else:
                wp.launch(kernels.update_velocities, dim=n, device=dev, inputs=[sub, solved])

    def _launch_broad_phase(self, sub: kernels.Substep) -> None:
        """Self-contact candidates of the substep, from the start positions (x_prev) and the predictions (x)."""
        n_faces = self.contacts.faces.shape[0]
        wp.launch(self_contact.contact_bounds, dim=n_faces, device=self.device,
                  inputs=[sub.x, sub.x_prev, self.contacts])
        self._face_bvh.refit()
        wp.launch(self_contact.find_self_contacts, dim=sub.x.shape[0], device=self.device,
                  inputs=[sub, self.contacts, self.model.settings.substeps])
        wp.launch(self_contact.sort_face_lists, dim=n_faces, device=self.device, inputs=[self.contacts])

    def _launch_projection(self, x: wp.array, fraction: float) -> None:
        hp = self.harmonic_projection
        worlds, n_chunks, n_modes = hp.partial.shape
        wp.launch(kernels.harmonic_partial_sums, dim=(worlds, n_chunks, n_modes), device=self.device, inputs=[x, hp])
        # Lanes as in a sweep: per vertex (its K modes), and per mode (its chunks' partial sums).
        lanes = self.sweep_lanes
        mode_lanes = cuda_sweep_lanes(worlds * n_modes) if self.device.is_cuda else 1
        wp.launch(kernels.harmonic_residual, dim=worlds * n_modes * mode_lanes, device=self.device,
                  inputs=[hp, fraction, mode_lanes])
        wp.launch(kernels.harmonic_project, dim=x.shape[0] * lanes, device=self.device, inputs=[hp, x, lanes])
