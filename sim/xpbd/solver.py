"""Host side of the XPBD cloth solver: constraint assembly (numpy) and frame stepping (Warp, CPU or CUDA).

A frame of length dt is split into `substeps`; each substep predicts positions, runs `iterations` Jacobi sweeps
over the distance constraints (and, for a high-res run, projects onto the harmonic constraint after each sweep),
and derives velocities. With body or self-collision on, the same steps use the kernels of `sim.xpbd.collision`
(contacts fused into them) plus, for self-collision, a broad phase once per substep. On CUDA the whole frame is
captured once as a graph and replayed; per-frame inputs (pin targets, harmonic targets, capsules) live in device
arrays that are overwritten before each replay.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from sim.xpbd import collision as ck
from sim.xpbd import kernels as k
from geometry.harmonics import lumped_mass
from geometry.mesh import bending_pairs, unique_edges


@dataclass(frozen=True)
class SolverSettings:
    """Everything that defines the integration; units are scene units (~m), seconds and kilograms."""
    dt: float = 1.0 / 60.0
    substeps: int = 8
    iterations: int = 75
    compression_allowance: float = 0.75  # stretch constraints allow compression down to this fraction of rest length
    stretch_compliance: float = 0.0      # XPBD compliance of stretch constraints (inverse stiffness, m/N)
    bending_compliance: float = 1.0e-3   # XPBD compliance of cross-edge bending links
    damping: float = 0.1                 # velocity decay rate (1/s): v <- v exp(-damping h) every substep
    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    density: float = 0.2                 # area density of the cloth (kg per square unit)
    relaxation: float = 1.5              # Jacobi over-relaxation, see solve_distance_constraints
    max_speed: float = 100.0             # a vertex faster than this (units/s) means the run has blown up
    bending: bool = True                 # physics switch: cross-edge bending links
    body_collision: bool = False         # physics switch: keep the cloth outside the body's capsules
    self_collision: bool = False         # physics switch: vertex-triangle self-contact
    collision_thickness: float = 0.005   # least distance of the cloth from every capsule surface
    friction: float = 0.3                # Coulomb coefficient against the (moving) body
    self_thickness: float = 0.004        # least distance of a vertex from a non-incident triangle

    def __post_init__(self):
        checks = {
            "dt": self.dt > 0, "substeps": self.substeps >= 1, "iterations": self.iterations >= 1,
            "compression_allowance": 0 < self.compression_allowance <= 1,
            "stretch_compliance": self.stretch_compliance >= 0, "bending_compliance": self.bending_compliance >= 0,
            "damping": self.damping >= 0, "density": self.density > 0,
            "relaxation": 0 < self.relaxation < 2, "max_speed": self.max_speed > 0,
            "collision_thickness": self.collision_thickness > 0, "friction": self.friction >= 0,
            "self_thickness": self.self_thickness > 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"solver setting '{bad[0]}' out of range: {getattr(self, bad[0])}")


@dataclass(frozen=True)
class DistanceConstraints:
    """Two-vertex constraints rest_min <= |x_i - x_j| <= rest_max with a compliance each."""
    pairs: np.ndarray       # (C, 2) int
    rest_min: np.ndarray    # (C,)
    rest_max: np.ndarray    # (C,)
    compliance: np.ndarray  # (C,)


def cloth_constraints(rest_vertices: np.ndarray, faces: np.ndarray, s: SolverSettings) -> DistanceConstraints:
    """Stretch constraints on every edge (compression allowed to `compression_allowance`) and, if bending is on,
    a link between the two vertices opposite each interior edge, at its rest length."""
    edges = unique_edges(faces)
    length = np.linalg.norm(rest_vertices[edges[:, 0]] - rest_vertices[edges[:, 1]], axis=1)
    parts = [(edges, s.compression_allowance * length, length, np.full(len(edges), s.stretch_compliance))]
    if s.bending:
        links = bending_pairs(faces)
        link_length = np.linalg.norm(rest_vertices[links[:, 0]] - rest_vertices[links[:, 1]], axis=1)
        parts.append((links, link_length, link_length, np.full(len(links), s.bending_compliance)))
    return DistanceConstraints(*(np.concatenate(p) for p in zip(*parts)))


@dataclass(frozen=True)
class HarmonicConstraint:
    """Hard constraint B^T M (x - S x_low) = 0 (compliance 0), solved by M-orthogonal projection.

    `mass_basis` = M B (V, K) gives the residual; `correction_basis` = P_free B (B^T M P_free B)^{-1} (V, K)
    maps a residual to the smallest (in the M-norm) correction that zeroes it without moving pinned vertices.
    """
    mass_basis: np.ndarray
    correction_basis: np.ndarray


def harmonic_constraint(basis: np.ndarray, mass: np.ndarray, pinned: np.ndarray) -> HarmonicConstraint:
    """Build the projection for an M-orthonormal basis B (V, K), lumped mass (V,) and the pinned vertex ids."""
    free = np.ones(len(mass), dtype=bool)
    free[pinned] = False
    free_basis = basis * free[:, None]
    gram = basis.T @ (mass[:, None] * free_basis)
    cond = np.linalg.cond(gram)
    if not np.isfinite(cond) or cond > 1e8:
        raise ValueError(f"pinned vertices leave the harmonic constraint unsatisfiable (condition number {cond:.3g})")
    return HarmonicConstraint(mass_basis=mass[:, None] * basis,
                              correction_basis=np.linalg.solve(gram, free_basis.T).T)


class UnstableSimulation(RuntimeError):
    """Positions became non-finite or a vertex exceeded the speed limit."""


# How far beyond the thickness (in mean rest edge lengths) contacts are prepared at the prediction, for the motion
# of the iterations: a vertex watches the capsules within one edge (the constraints may pull it that far: a
# watched capsule is swept, so a vertex pulled across a thin limb stays on its side), and self-contact pairs
# within a quarter edge become candidates (each costs a little in every iteration).
BODY_MARGIN = 1.0
SELF_MARGIN = 0.25


class ClothSolver:
    """Steps a cloth mesh frame by frame on one Warp device.

    Inputs per frame: the pin targets at the end of the frame (P, 3), for a constrained run the harmonic target
    B^T M S x_low at the end of the frame (K, 3) and, with body collision, the capsule end points at the end of
    the frame (P, 2, 3); all are interpolated linearly across substeps from the previous frame's values.
    `capsules` (P, 2, 3) and `capsule_radii` (P, 2) give the capsules at frame 0 and their radii at a and b.
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, settings: SolverSettings, device: str,
                 pinned: np.ndarray, initial_positions: np.ndarray | None = None,
                 harmonic: HarmonicConstraint | None = None, harmonic_target: np.ndarray | None = None,
                 capsules: np.ndarray | None = None, capsule_radii: np.ndarray | None = None):
        self.settings = settings
        self.device = wp.get_device(device)
        n = len(rest_vertices)
        s = settings
        h = s.dt / s.substeps
        mass = s.density * lumped_mass(rest_vertices, faces)
        pinned = np.asarray(pinned, dtype=np.int64)
        inv_mass = 1.0 / mass
        inv_mass[pinned] = 0.0
        pin_slot = np.full(n, -1, dtype=np.int32)
        pin_slot[pinned] = np.arange(len(pinned), dtype=np.int32)
        x0 = rest_vertices if initial_positions is None else initial_positions

        con = cloth_constraints(rest_vertices, faces, s)
        offsets, neighbor, constraint = _vertex_incidence(con.pairs, n)
        count = np.diff(offsets)
        scale = s.relaxation / np.maximum(count[con.pairs[:, 0]], count[con.pairs[:, 1]])

        arr = self._array
        self.x = arr(x0, wp.vec3)
        self.x_prev = arr(x0, wp.vec3)
        self.x_work = arr(x0, wp.vec3)
        self.v = arr(np.zeros((n, 3)), wp.vec3)
        self.inv_mass = arr(inv_mass, float)
        self.pin_slot = arr(pin_slot, int)
        start = x0[pinned] if len(pinned) else np.zeros((1, 3))
        self.pin_start, self.pin_end = arr(start, wp.vec3), arr(start, wp.vec3)
        self.offsets, self.neighbor, self.constraint = arr(offsets, int), arr(neighbor, int), arr(constraint, int)
        self.rest_min, self.rest_max = arr(con.rest_min, float), arr(con.rest_max, float)
        self.alpha_tilde = arr(con.compliance / (h * h), float)
        self.scale = arr(scale, float)
        self.lambdas = (arr(np.zeros(len(con.pairs)), float), arr(np.zeros(len(con.pairs)), float))
        # One flag per substep (blow-up) and a last one for overflowing self-contact lists.
        self.flags = arr(np.zeros(s.substeps + 1), int)
        self.n_pins = len(pinned)
        self.n_constraints = len(con.pairs)

        self.harmonic = harmonic is not None
        if self.harmonic:
            n_modes = harmonic.mass_basis.shape[1]
            self.rows_per_chunk = 64
            n_chunks = math.ceil(n / self.rows_per_chunk)
            self.mass_basis = wp.array(harmonic.mass_basis.astype(np.float32), dtype=float, device=self.device)
            self.correction_basis_t = wp.array(np.ascontiguousarray(harmonic.correction_basis.T, dtype=np.float32),
                                               dtype=float, device=self.device)
            self.partial = wp.zeros((n_chunks, n_modes), dtype=wp.vec3, device=self.device)
            self.residual = wp.zeros(n_modes, dtype=wp.vec3, device=self.device)
            target = np.zeros((n_modes, 3)) if harmonic_target is None else harmonic_target
            self.target_start, self.target_end = arr(target, wp.vec3), arr(target, wp.vec3)

        edges = unique_edges(faces)
        mean_edge = float(np.linalg.norm(rest_vertices[edges[:, 0]] - rest_vertices[edges[:, 1]], axis=1).mean())
        self.body = self._body(capsules, capsule_radii, s.collision_thickness + BODY_MARGIN * mean_edge, n)
        self.contacts = self._self_contacts(np.asarray(faces), s.self_thickness + SELF_MARGIN * mean_edge, n)
        self._graph = None

    def _array(self, data: np.ndarray, dtype) -> wp.array:
        np_dtype = np.int32 if dtype in (int, wp.vec3i) else np.float32
        return wp.array(np.ascontiguousarray(data, dtype=np_dtype), dtype=dtype, device=self.device)

    def _body(self, capsules, radii, reach: float, n: int) -> ck.Body:
        """The capsules and per-vertex body-contact state (with body collision off: no capsules, so the kernels'
        capsule loops are empty)."""
        s = self.settings
        body = ck.Body()
        body.near = self._array(np.zeros(n), int)
        body.push = self._array(np.zeros(n), float)
        if not s.body_collision:
            if capsules is not None or radii is not None:
                raise ValueError("capsules were given but settings.body_collision is off")
            return body
        if capsules is None or radii is None:
            raise ValueError("body_collision needs capsules (P, 2, 3) and capsule_radii (P, 2) at frame 0")
        capsules = np.asarray(capsules, dtype=np.float64)
        radii = np.asarray(radii, dtype=np.float64)
        if capsules.ndim != 3 or capsules.shape[1:] != (2, 3) or radii.shape != capsules.shape[:2]:
            raise ValueError(f"capsules must be (P, 2, 3) and capsule_radii (P, 2); got {capsules.shape} and "
                             f"{radii.shape}")
        if not 1 <= len(capsules) <= 255:  # a vertex lists the capsules it watches as bytes of one int32
            raise ValueError(f"body collision takes 1 to 255 capsules, got {len(capsules)}")
        length = np.linalg.norm(capsules[:, 1] - capsules[:, 0], axis=1)
        if (radii <= 0).any() or (length <= np.abs(radii[:, 0] - radii[:, 1])).any():
            raise ValueError("capsule radii must be positive and each segment longer than the difference of its "
                             "end radii")
        body.start = self._array(capsules, wp.vec3)
        body.end = self._array(capsules, wp.vec3)
        body.radius = self._array(radii, float)
        body.thickness = s.collision_thickness
        body.reach = reach
        body.friction = s.friction
        return body

    def _self_contacts(self, faces: np.ndarray, reach: float, n: int) -> ck.SelfContacts:
        """Mesh, broad phase and contact lists for self-collision (with it off: empty lists only).

        The triangle BVH is built once over the initial boxes with the same (SAH) builder on every device, so CPU
        and CUDA traverse identical trees; each substep only refits it."""
        s = self.settings
        sc = ck.SelfContacts()
        sc.vertex_count = self._array(np.zeros(n), int)
        if not s.self_collision:  # no lists and no triangles around any vertex: the iterations find no contact
            sc.face_offsets = self._array(np.zeros(n + 1), int)
            return sc
        arr = self._array
        sc.faces = arr(faces, wp.vec3i)
        face_ids = np.repeat(np.arange(len(faces)), 3)
        order = np.argsort(faces.ravel(), kind="stable")
        sc.face_offsets = arr(np.concatenate([[0], np.cumsum(np.bincount(faces.ravel(), minlength=n))]), int)
        sc.vertex_faces = arr(face_ids[order], int)
        edge_offsets, neighbors, _ = _vertex_incidence(unique_edges(faces), n)
        if np.diff(edge_offsets).max() > ck.MAX_VALENCE:
            raise ValueError(f"self-collision handles vertices of up to {ck.MAX_VALENCE} neighbours; this mesh has "
                             f"one with {np.diff(edge_offsets).max()}")
        sc.edge_offsets, sc.vertex_neighbors = arr(edge_offsets, int), arr(neighbors, int)
        sc.face_lower = arr(np.zeros((len(faces), 3)), wp.vec3)
        sc.face_upper = arr(np.zeros((len(faces), 3)), wp.vec3)
        sc.vertex_contacts = arr(np.zeros((n, ck.VERTEX_LIST)), int)
        sc.face_contacts = arr(np.zeros((len(faces), ck.FACE_LIST)), int)
        sc.face_count = arr(np.zeros(len(faces)), int)
        sc.thickness = s.self_thickness
        sc.reach = reach
        wp.launch(ck.contact_bounds, dim=len(faces), device=self.device, inputs=[self.x, self.x, sc])
        self._face_bvh = wp.Bvh(sc.face_lower, sc.face_upper, constructor="sah")
        sc.face_bvh = self._face_bvh.id
        return sc

    def step(self, pin_targets: np.ndarray | None = None, harmonic_target: np.ndarray | None = None,
             capsules: np.ndarray | None = None) -> None:
        """Advance one frame. Raises UnstableSimulation naming the first bad substep."""
        if self.settings.body_collision:
            if capsules is None or np.shape(capsules) != tuple(self.body.end.shape) + (3,):
                raise ValueError(f"body_collision needs the capsules at the end of the frame, shape "
                                 f"{tuple(self.body.end.shape) + (3,)}; got "
                                 f"{None if capsules is None else np.shape(capsules)}")
            self.body.start.assign(self.body.end)
            self.body.end.assign(np.asarray(capsules, dtype=np.float32))
        elif capsules is not None:
            raise ValueError("capsules were given but settings.body_collision is off")
        if self.n_pins:
            self.pin_start.assign(self.pin_end)
            self.pin_end.assign(np.asarray(pin_targets, dtype=np.float32))
        if self.harmonic:
            self.target_start.assign(self.target_end)
            self.target_end.assign(np.asarray(harmonic_target, dtype=np.float32))
        self.flags.zero_()
        if self.device.is_cuda:
            if self._graph is None:
                for module in (k, ck):  # compile before capture: no JIT inside a graph
                    wp.load_module(module, device=self.device)
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch_frame()
                self._graph = capture.graph
            wp.capture_launch(self._graph)
        else:
            self._launch_frame()
        flags = self.flags.numpy()
        if flags[-1]:
            warnings.warn("self-contact lists overflowed; the extra contacts of this frame were dropped",
                          RuntimeWarning, stacklevel=2)
        if flags[:-1].any():
            raise UnstableSimulation(f"substep {int(np.argmax(flags[:-1]))}")

    def positions(self) -> np.ndarray:
        return self.x.numpy().astype(np.float64)

    def velocities(self) -> np.ndarray:
        return self.v.numpy().astype(np.float64)

    def set_velocities(self, velocities: np.ndarray) -> None:
        self.v.assign(np.asarray(velocities, dtype=np.float32))

    def _launch_frame(self) -> None:
        s = self.settings
        h = s.dt / s.substeps
        n = self.x.shape[0]
        dev = self.device
        gravity = wp.vec3(*s.gravity)
        damping_factor = math.exp(-s.damping * h)
        collide = s.body_collision or s.self_collision
        for sub in range(s.substeps):
            f0, f1 = sub / s.substeps, (sub + 1) / s.substeps
            predict = [self.x, self.v, self.inv_mass, self.pin_slot, self.pin_start, self.pin_end, f1, gravity, h,
                       damping_factor, self.x_prev]
            if s.body_collision:
                wp.launch(ck.predict_with_body, dim=n, device=dev, inputs=predict + [self.body, f0])
            else:
                wp.launch(k.predict_positions, dim=n, device=dev, inputs=predict)
            if s.self_collision:
                self._launch_broad_phase()
            # Ping-pong between x and x_work; the lambdas ping-pong in step.
            buffers = (self.x, self.x_work)
            for it in range(s.iterations):
                src, dst = buffers[it % 2], buffers[(it + 1) % 2]
                inputs = [src, self.inv_mass, self.offsets, self.neighbor, self.constraint, self.rest_min,
                          self.rest_max, self.alpha_tilde, self.scale, self.lambdas[it % 2],
                          0.0 if it == 0 else 1.0, self.lambdas[(it + 1) % 2], dst]
                if collide:
                    wp.launch(ck.solve_with_collisions, dim=n, device=dev,
                              inputs=inputs + [self.contacts, self.body, f1])
                else:
                    wp.launch(k.solve_distance_constraints, dim=n, device=dev, inputs=inputs)
                if self.harmonic:
                    self._launch_projection(dst, f1)
            solved = buffers[s.iterations % 2]
            state = [solved, self.x_prev, 1.0 / h, s.max_speed, sub, self.x, self.v, self.flags]
            if collide:
                wp.launch(ck.finish_substep, dim=n, device=dev, inputs=state + [self.inv_mass, self.body, f0, f1])
            else:
                wp.launch(k.update_velocities, dim=n, device=dev, inputs=state)

    def _launch_broad_phase(self) -> None:
        """Self-contact candidates of the substep, from the start positions (x_prev) and the predictions (x)."""
        n_faces = self.contacts.faces.shape[0]
        wp.launch(ck.contact_bounds, dim=n_faces, device=self.device, inputs=[self.x, self.x_prev, self.contacts])
        self._face_bvh.refit()
        wp.launch(ck.find_self_contacts, dim=self.x.shape[0], device=self.device,
                  inputs=[self.x, self.x_prev, self.inv_mass, self.contacts, self.flags, self.settings.substeps])
        wp.launch(ck.sort_face_lists, dim=n_faces, device=self.device, inputs=[self.contacts])

    def _launch_projection(self, x: wp.array, fraction: float) -> None:
        n_chunks, n_modes = self.partial.shape
        wp.launch(k.harmonic_partial_sums, dim=(n_chunks, n_modes), device=self.device,
                  inputs=[x, self.mass_basis, self.rows_per_chunk, self.partial])
        wp.launch(k.harmonic_residual, dim=n_modes, device=self.device,
                  inputs=[self.partial, self.target_start, self.target_end, fraction, self.residual])
        wp.launch(k.harmonic_project, dim=x.shape[0], device=self.device,
                  inputs=[self.residual, self.correction_basis_t, x])


def _vertex_incidence(pairs: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR of constraints per vertex: offsets (V+1,), the other endpoint and the constraint id of each entry."""
    ids = np.arange(len(pairs))
    first = np.concatenate([pairs[:, 0], pairs[:, 1]])
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    cid = np.concatenate([ids, ids])
    order = np.argsort(first, kind="stable")
    offsets = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(first, minlength=n_vertices), out=offsets[1:])
    return offsets, other[order], cid[order]

