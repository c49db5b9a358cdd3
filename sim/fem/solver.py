"""Host side of the quasi-static FEM solver: each frame, the nodes the bones drive move to their targets and the
free nodes to a minimum of the elastic energy, found by Newton's method (Warp, CPU or CUDA; the same kernels).

A Newton step solves H d = -g by conjugate gradients preconditioned with the inverses of H's 3 x 3 diagonal
blocks (sim.fem.pcg), to a relative tolerance (an inexact Newton step: far from the minimum an exact one buys
nothing). H is the exact Hessian where it is positive definite, which converges quadratically; where CG meets
negative curvature or d does not descend, the step is solved again with each tet's Hessian projected onto the
positive semi-definite matrices (projected Newton, which always descends). Projecting every step instead
converges only linearly (a factor ~0.5 a step on a twisted beam): near rest, the energy's twist eigenvalues
are ~0 and any compression makes them negative, so projection changes H everywhere in a hand, not only in the
few elements that are far from convex. A backtracking line search (Armijo) on each world's energy
takes the step or a halving of it. A frame starts where the last one ended (warm start); its bone motion can be
applied in `load_steps` increments, each minimised. A world has converged when its residual (the largest force
on a free node over mu h^2, FemSettings) is within tolerance; `solver.last_report` says per world how far each
frame got, and a frame that does not converge within `newton_iterations` is reported, not an error (the next
frame goes on from it). A non-finite energy is UnstableSimulation. A guess of the nodes' motion over the frame
(FemInputs.node_motion) moves the warm start along with the bones.

`worlds` copies of the model are stepped together, each with its own targets: one block-diagonal system, one CG
(its residual the worst world's, so a batch costs one solve's launches), a step length per world.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from sim.fem.energy import ElasticEnergy
from sim.fem.model import FemModel
from sim.fem.pcg import BlockJacobiCG
from sim.solver import Solver, UnstableSimulation

ARMIJO = 1.0e-4   # sufficient decrease: accept a step that achieves this share of the decrease its slope promises
# Near the minimum a step's true decrease falls below the rounding of the energy sum (float64, ~1e-16 of each term):
# a change within this share of the energy counts as no increase, so the last Newton steps are not refused.
ROUNDING = 1.0e-12


@dataclass(frozen=True, eq=False)
class FemState:
    """The nodes' positions of every world, (B N,) vec3d, world after world; made by FemSolver (`solver.state`)."""
    positions: wp.array
    worlds: int
    surface: "SurfaceEmbedding | None" = None

    def read_nodes(self) -> np.ndarray:
        """(B, N, 3) float64 copy on the host."""
        return self.positions.numpy().reshape(self.worlds, -1, 3).copy()

    def read_world_positions(self) -> np.ndarray:
        """(B, S, 3) float32: the embedded surface's vertices (or the nodes, without an embedding)."""
        if self.surface is None:
            return self.read_nodes().astype(np.float32)
        return self.surface.evaluate(self.positions)


@dataclass(frozen=True)
class FemInputs:
    """The targets of the driven nodes at the end of the frame, (B, D, 3) (or (D, 3) with one world), in the
    order of FemModel.driven; optionally a guess of every node's motion over the frame, (B, N, 3) (or (N, 3)),
    such as the nodes' linear blend skinning at the frame's end minus at its start: added to where the last frame
    left the free nodes, it starts the minimisation near its answer when the bones move far in a frame (from the
    last frame alone, the flesh next to a bone that turned 20 degrees starts inverted, and Newton's method can
    stall in an inverted local minimum)."""
    driven_targets: np.ndarray
    node_motion: np.ndarray | None = None


@dataclass(frozen=True)
class FrameReport:
    """How the last frame's minimisation went, per world (of its last load step)."""
    residual: np.ndarray          # (B,) the final residual (FemSettings)
    newton_iterations: np.ndarray  # (B,) Newton steps taken, all load steps together
    cg_iterations: int            # CG iterations of the frame (all worlds share each solve)
    converged: np.ndarray         # (B,) residual within tolerance at the end of every load step


@wp.kernel
def _embed(x: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), tet_of: wp.array(dtype=wp.int32),
           weights: wp.array(dtype=wp.vec4d), n_nodes: int, n_out: int, out: wp.array(dtype=wp.vec3)):
    tid = wp.tid()
    world = tid // n_out
    s = tid - world * n_out
    tet = tets[tet_of[s]]
    w = weights[s]
    offset = world * n_nodes
    p = w[0] * x[offset + tet[0]] + w[1] * x[offset + tet[1]] + w[2] * x[offset + tet[2]] + w[3] * x[offset + tet[3]]
    out[tid] = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))


class SurfaceEmbedding:
    """The surface vertices' barycentric places in the tets, evaluated on the device."""

    def __init__(self, model: FemModel, tets: wp.array, worlds: int, device):
        tet_of, weights = model.embedding
        self.tets, self.worlds, self.n_nodes, self.n_out = tets, worlds, len(model.rest_vertices), len(tet_of)
        self.tet_of = wp.array(tet_of.astype(np.int32), dtype=wp.int32, device=device)
        self.weights = wp.array(weights, dtype=wp.vec4d, device=device)
        self.out = wp.zeros(worlds * self.n_out, dtype=wp.vec3, device=device)

    def evaluate(self, positions: wp.array) -> np.ndarray:
        wp.launch(_embed, dim=self.worlds * self.n_out, inputs=[positions, self.tets, self.tet_of, self.weights,
                                                                self.n_nodes, self.n_out, self.out],
                  device=self.out.device)
        return self.out.numpy().reshape(self.worlds, self.n_out, 3).copy()


@wp.kernel
def _place_driven(x: wp.array(dtype=wp.vec3d), driven: wp.array(dtype=wp.int32), start: wp.array(dtype=wp.vec3d),
                  end: wp.array(dtype=wp.vec3d), f: wp.float64, n_driven: int, n_nodes: int):
    tid = wp.tid()
    world = tid // n_driven
    x[world * n_nodes + driven[tid - world * n_driven]] = start[tid] + f * (end[tid] - start[tid])


@wp.kernel
def _add(x: wp.array(dtype=wp.vec3d), dx: wp.array(dtype=wp.vec3d)):
    tid = wp.tid()
    x[tid] = x[tid] + dx[tid]


@wp.kernel
def _residual(g: wp.array(dtype=wp.vec3d), n_nodes: int, scale: wp.float64, out: wp.array(dtype=wp.float64)):
    tid = wp.tid()
    r = wp.length(g[tid]) * scale
    if wp.isnan(r):
        r = wp.float64(wp.inf)      # a maximum would pass over NaN: make it the largest value instead
    wp.atomic_max(out, tid // n_nodes, r)


@wp.kernel
def _negate(g: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    tid = wp.tid()
    out[tid] = -g[tid]


@wp.kernel
def _slope(g: wp.array(dtype=wp.vec3d), d: wp.array(dtype=wp.vec3d), n_nodes: int, out: wp.array(dtype=wp.float64)):
    tid = wp.tid()
    wp.atomic_add(out, tid // n_nodes, wp.dot(g[tid], d[tid]))


@wp.kernel
def _trial(x: wp.array(dtype=wp.vec3d), d: wp.array(dtype=wp.vec3d), step: wp.array(dtype=wp.float64), n_nodes: int,
           out: wp.array(dtype=wp.vec3d)):
    tid = wp.tid()
    out[tid] = x[tid] + step[tid // n_nodes] * d[tid]


class FemSolver(Solver[FemModel, FemState, FemInputs]):
    """Steps a FEM model frame by frame on one Warp device. The state starts at `initial_positions` ((N, 3) for
    every world, or (B, N, 3); default: the rest positions), which must put the driven nodes where their frame-0
    targets are; the first step moves them from there."""

    def __init__(self, model: FemModel, device: str, worlds: int = 1, initial_positions: np.ndarray | None = None):
        if not (isinstance(worlds, int) and worlds >= 1):
            raise ValueError(f"worlds must be a positive integer, got {worlds!r}")
        self.model, self.worlds = model, worlds
        self.device = wp.get_device(device)
        n = len(model.rest_vertices)
        x0 = model.rest_vertices if initial_positions is None else np.asarray(initial_positions, dtype=np.float64)
        x0 = np.broadcast_to(x0, (worlds, n, 3)) if x0.shape == (n, 3) else x0
        if x0.shape != (worlds, n, 3) or not np.isfinite(x0).all():
            raise ValueError(f"initial_positions must be finite, (N, 3) or (B, N, 3) = {(worlds, n, 3)}; got "
                             f"{x0.shape}")
        self.energy = ElasticEnergy(model, self.device, worlds)
        array = lambda a, dtype=wp.vec3d: wp.array(np.ascontiguousarray(a), dtype=dtype, device=self.device)  # noqa
        zeros = lambda shape, dtype=wp.vec3d: wp.zeros(shape, dtype=dtype, device=self.device)  # noqa: E731
        surface = None if model.embedding is None else SurfaceEmbedding(model, self.energy.tets, worlds, self.device)
        self.state = FemState(array(x0.reshape(-1, 3)), worlds, surface)
        self._driven = array(model.driven.astype(np.int32), wp.int32)
        self._targets = array(x0[:, model.driven].reshape(-1, 3))        # where the driven nodes are now
        self._next_targets = zeros(worlds * len(model.driven))
        self._gradient, self._rhs, self._step = zeros(worlds * n), zeros(worlds * n), zeros(worlds * n)
        self._trial, self._motion = zeros(worlds * n), zeros(worlds * n)
        self._per_world = {name: zeros(worlds, wp.float64) for name in ("energy", "trial", "slope", "residual",
                                                                           "length")}
        rest, tets = model.rest_vertices, model.tets
        edges = np.concatenate([rest[tets[:, a]] - rest[tets[:, b]] for a in range(4) for b in range(a + 1, 4)])
        mean_edge = float(np.linalg.norm(edges, axis=1).mean())
        self.residual_scale = 1.0 / (self.energy.mu * mean_edge ** 2)
        self._cg = BlockJacobiCG(worlds, n, self.device)
        self.last_report: FrameReport | None = None

    def step(self, state: FemState, inputs: FemInputs) -> None:
        targets = np.asarray(inputs.driven_targets, dtype=np.float64)
        d = len(self.model.driven)
        targets = targets[None] if targets.shape == (d, 3) and self.worlds == 1 else targets
        if targets.shape != (self.worlds, d, 3) or not np.isfinite(targets).all():
            raise ValueError(f"driven_targets must be finite, shape {(self.worlds, d, 3)}; got {targets.shape}")
        self._next_targets.assign(targets.reshape(-1, 3))
        s = self.model.settings
        motion = None
        if inputs.node_motion is not None:
            motion = np.asarray(inputs.node_motion, dtype=np.float64)
            n = len(self.model.rest_vertices)
            motion = motion[None] if motion.shape == (n, 3) and self.worlds == 1 else motion
            if motion.shape != (self.worlds, n, 3) or not np.isfinite(motion).all():
                raise ValueError(f"node_motion must be finite, shape {(self.worlds, n, 3)}; got {motion.shape}")
            self._motion.assign(motion.reshape(-1, 3) / s.load_steps)
        newton = np.zeros(self.worlds, dtype=np.int64)
        converged = np.ones(self.worlds, dtype=bool)
        cg_total = 0
        for load in range(1, s.load_steps + 1):
            if motion is not None:
                wp.launch(_add, dim=len(state.positions), inputs=[state.positions, self._motion], device=self.device)
            wp.launch(_place_driven, dim=self.worlds * d,
                      inputs=[state.positions, self._driven, self._targets, self._next_targets,
                              wp.float64(load / s.load_steps), d, len(self.model.rest_vertices)],
                      device=self.device)
            residual, steps, cg = self._minimise(state.positions)
            newton += steps
            cg_total += cg
            converged &= residual <= s.residual_tolerance
        wp.copy(self._targets, self._next_targets)
        self.last_report = FrameReport(residual, newton, cg_total, converged)

    def residual(self, x: wp.array) -> np.ndarray:
        """(B,) each world's residual at x (and the gradient there, left in self._gradient)."""
        self.energy.gradient(x, self._gradient)
        out = self._per_world["residual"]
        out.zero_()
        wp.launch(_residual, dim=len(x), inputs=[self._gradient, len(self.model.rest_vertices),
                                                 wp.float64(self.residual_scale), out], device=self.device)
        return out.numpy().copy()

    def _minimise(self, x: wp.array) -> tuple[np.ndarray, np.ndarray, int]:
        """Newton's method from x to the energy's minimum with the driven nodes held: (residual (B,), Newton steps
        (B,), CG iterations)."""
        s = self.model.settings
        steps = np.zeros(self.worlds, dtype=np.int64)
        cg_iterations = 0
        for _ in range(s.newton_iterations):
            residual = self.residual(x)
            active = residual > s.residual_tolerance
            if not np.isfinite(residual).all():
                raise UnstableSimulation(int(np.flatnonzero(~np.isfinite(residual))[0]), 0,
                                         "the elastic forces are not finite")
            if not active.any():
                return residual, steps, cg_iterations
            wp.launch(_negate, dim=len(x), inputs=[self._gradient, self._rhs], device=self.device)
            cg_iterations += self._newton_direction(x, active)
            self._line_search(x, active)
            steps += active
        return self.residual(x), steps, cg_iterations

    def _newton_direction(self, x: wp.array, active: np.ndarray) -> int:
        """self._step <- the Newton direction at x (the exact Hessian's, else the projected one's); returns the CG
        iterations spent."""
        s = self.model.settings
        iterations = 0
        for project in (False, True):
            hessian = self.energy.assemble_hessian(x, project=project)
            done, indefinite = self._cg.solve(hessian, self._rhs, self._step, s.cg_tolerance, s.cg_iterations)
            iterations += done
            if not (active & (indefinite | (self._slopes() >= 0))).any():
                break
        return iterations

    def _slopes(self) -> np.ndarray:
        """(B,) g . d of each world: the energy's rate of change along the step."""
        slope = self._per_world["slope"]
        slope.zero_()
        wp.launch(_slope, dim=len(self._step), inputs=[self._gradient, self._step, len(self.model.rest_vertices),
                                                        slope], device=self.device)
        return slope.numpy().copy()

    def _line_search(self, x: wp.array, active: np.ndarray) -> None:
        """x += t d per world, t the first of 1, 1/2, 1/4, ... that decreases the energy enough (Armijo); a world
        that has converged (not `active`) or finds no such t stays."""
        n = len(self.model.rest_vertices)
        energy, trial, length = (self._per_world[k] for k in ("energy", "trial", "length"))
        self.energy.energy(x, energy)
        e0, g_d = energy.numpy().copy(), self._slopes()
        t = np.where(active & (g_d < 0), 1.0, 0.0)
        accepted = t == 0.0
        for _ in range(self.model.settings.line_search_halvings + 1):
            length.assign(np.where(accepted, 0.0, t))
            wp.launch(_trial, dim=len(x), inputs=[x, self._step, length, n, self._trial], device=self.device)
            self.energy.energy(self._trial, trial)
            e = trial.numpy()
            accepted |= np.isfinite(e) & (e <= e0 + ARMIJO * t * g_d + ROUNDING * np.abs(e0))
            if accepted.all():
                break
            t = np.where(accepted, t, 0.5 * t)
        t = np.where(accepted, t, 0.0)
        length.assign(t)
        wp.launch(_trial, dim=len(x), inputs=[x, self._step, length, n, self._trial], device=self.device)
        wp.copy(x, self._trial)
