"""Host side of the XPBD cloth solver: constraint assembly (numpy) and frame stepping (Warp, CPU or CUDA).

A frame of length dt is split into `substeps`; each substep predicts positions, runs `iterations` Jacobi sweeps
over the distance constraints (and, for a high-res run, projects onto the harmonic constraint after each sweep),
and derives velocities. On CUDA the whole frame is captured once as a graph and replayed; per-frame inputs (pin
targets, harmonic targets) live in device arrays that are overwritten before each replay.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from sim import xpbd_kernels as k
from sim.harmonics import lumped_mass
from sim.mesh import bending_pairs, unique_edges


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

    def __post_init__(self):
        checks = {
            "dt": self.dt > 0, "substeps": self.substeps >= 1, "iterations": self.iterations >= 1,
            "compression_allowance": 0 < self.compression_allowance <= 1,
            "stretch_compliance": self.stretch_compliance >= 0, "bending_compliance": self.bending_compliance >= 0,
            "damping": self.damping >= 0, "density": self.density > 0,
            "relaxation": 0 < self.relaxation < 2, "max_speed": self.max_speed > 0,
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


class ClothSolver:
    """Steps a cloth mesh frame by frame on one Warp device.

    Inputs per frame: the pin targets at the end of the frame (P, 3) and, for a constrained run, the harmonic
    target B^T M S x_low at the end of the frame (K, 3); both are interpolated linearly across substeps from the
    previous frame's values.
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray, settings: SolverSettings, device: str,
                 pinned: np.ndarray, initial_positions: np.ndarray | None = None,
                 harmonic: HarmonicConstraint | None = None, harmonic_target: np.ndarray | None = None):
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
        self.unstable = arr(np.zeros(s.substeps), int)
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
        self._graph = None

    def _array(self, data: np.ndarray, dtype) -> wp.array:
        np_dtype = np.int32 if dtype is int else np.float32
        return wp.array(np.ascontiguousarray(data, dtype=np_dtype), dtype=dtype, device=self.device)

    def step(self, pin_targets: np.ndarray | None = None, harmonic_target: np.ndarray | None = None) -> None:
        """Advance one frame. Raises UnstableSimulation naming the first bad substep."""
        if self.n_pins:
            self.pin_start.assign(self.pin_end)
            self.pin_end.assign(np.asarray(pin_targets, dtype=np.float32))
        if self.harmonic:
            self.target_start.assign(self.target_end)
            self.target_end.assign(np.asarray(harmonic_target, dtype=np.float32))
        self.unstable.zero_()
        if self.device.is_cuda:
            if self._graph is None:
                wp.load_module(k, device=self.device)  # compile before capture: no JIT inside a graph
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch_frame()
                self._graph = capture.graph
            wp.capture_launch(self._graph)
        else:
            self._launch_frame()
        flags = self.unstable.numpy()
        if flags.any():
            raise UnstableSimulation(f"substep {int(np.argmax(flags))}")

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
        for sub in range(s.substeps):
            fraction = (sub + 1) / s.substeps
            wp.launch(k.predict_positions, dim=n, device=dev,
                      inputs=[self.x, self.v, self.inv_mass, self.pin_slot, self.pin_start, self.pin_end, fraction,
                              gravity, h, damping_factor, self.x_prev])
            # Ping-pong between x and x_work; the lambdas ping-pong in step.
            buffers = (self.x, self.x_work)
            for it in range(s.iterations):
                src, dst = buffers[it % 2], buffers[(it + 1) % 2]
                wp.launch(k.solve_distance_constraints, dim=n, device=dev,
                          inputs=[src, self.inv_mass, self.offsets, self.neighbor, self.constraint, self.rest_min,
                                  self.rest_max, self.alpha_tilde, self.scale, self.lambdas[it % 2],
                                  0.0 if it == 0 else 1.0, self.lambdas[(it + 1) % 2], dst])
                if self.harmonic:
                    self._launch_projection(dst, fraction)
            solved = buffers[s.iterations % 2]
            wp.launch(k.update_velocities, dim=n, device=dev,
                      inputs=[solved, self.x_prev, 1.0 / h, s.max_speed, sub, self.x, self.v, self.unstable])

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

