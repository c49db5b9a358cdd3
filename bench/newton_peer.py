"""The peer a user would pick instead of this solver: NVIDIA Newton's XPBD, on the same cloth, pins and budget.

Used by `bench/batched_sim.py --peer newton` so that every ratio comes from one run (issue 12). Newton is not a
project dependency: install it beside the project's pinned warp-lang (`pip install --no-deps newton==1.8.0`;
Newton 1.8 asks for warp-lang >= 1.17); without it the bench prints one line saying so and skips these rows.

What is compared, per B: B copies of the cloth hanging from their pins under gravity, no body and no contact
(Newton's XPBD has no triangle self-contact, only particle-particle contact), the paper's budget (substeps x
iterations per 1/60 s frame), one CUDA graph per frame on both sides. Our side: stretch constraints on the edges and
cross-edge bending links (`sim.xpbd`); Newton's: a distance constraint ("spring") on every edge and a dihedral
bending constraint on every interior edge, B worlds of one model (`ModelBuilder.replicate`). The constraint types
differ in form, not in count or in what one iteration touches, so the times compare two XPBD implementations doing
the same amount of work.

Stiffness: Newton's XPBD adds up every constraint's correction of a particle (Jacobi, no averaging), so a spring
much stiffer than the particle masses allow diverges (an inextensible spring blows the pants up within a frame). Its
springs get the stiffest value that stays stable, ke = 1 / (valence h^2 max(w_i + w_j)) (each correction at most
1/valence of the violation); ours keep the scene's compliance (0: inextensible). Each row reports the largest edge
stretch the run ends with, so what the stiffness buys is on the table beside the time.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np
import warp as wp

from geometry.harmonics import lumped_mass
from geometry.mesh import unique_edges
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings

NEWTON_VERSION = "1.8.0"
BENDING_KE = 1.0e-2   # Newton's dihedral stiffness: soft, as our bending links are (its cost does not depend on it)


@dataclasses.dataclass(frozen=True)
class HangingRun:
    ms: float             # median per batch frame
    stretch: float        # largest edge length / rest length over all worlds at the end


def newton_missing() -> str | None:
    """Why Newton cannot run here, or None when it can."""
    try:
        import newton  # noqa: F401, PLC0415
    except ImportError as err:
        return f"Newton is not installed ({err.msg}; pip install --no-deps newton=={NEWTON_VERSION})"
    return None


def ours_hanging(vertices: np.ndarray, faces: np.ndarray, pins: np.ndarray, worlds: int, settings: SolverSettings,
                 device: str, frames: int, warmup: int) -> HangingRun:
    """This project's solver on B hanging copies (pins held still, no contact)."""
    hanging = dataclasses.replace(settings, body_collision=False, self_collision=False)
    solver = ClothSolver(ClothModel(vertices, faces, hanging, pins), device, worlds=worlds)
    held = FrameInputs(pin_targets=np.broadcast_to(vertices[pins], (worlds, len(pins), 3)).copy())

    def frame() -> None:
        solver.step(solver.state, held)
        solver.state.positions.numpy()  # what a stage stores each frame; also synchronises the device
    ms = _median_ms(frame, frames, warmup)
    return HangingRun(ms, _checked_stretch(solver.state.read_world_positions(), vertices, faces, pins))


def newton_hanging(vertices: np.ndarray, faces: np.ndarray, pins: np.ndarray, worlds: int, settings: SolverSettings,
                   device: str, frames: int, warmup: int) -> HangingRun:
    """Newton's XPBD on the same B hanging copies."""
    import newton  # noqa: PLC0415  (optional: newton_missing() says whether it is there)

    h = settings.dt / settings.substeps
    gravity = tuple(float(g) for g in settings.gravity)
    cloth = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=gravity)
    cloth.add_cloth_mesh(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
                         vertices=[wp.vec3(*v) for v in np.asarray(vertices, dtype=float)],
                         indices=np.asarray(faces).ravel().tolist(), density=settings.density, add_springs=True,
                         spring_ke=_stable_spring_ke(vertices, faces, pins, settings.density, h), spring_kd=0.0,
                         edge_ke=BENDING_KE, edge_kd=0.0,
                         particle_radius=0.0)   # radius 0: no particle-particle contact (none on our side)
    for i in pins:
        cloth.particle_mass[int(i)] = 0.0        # zero mass: kinematic, held where it is (Newton's pinning)
    scene = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=gravity)
    scene.replicate(cloth, worlds)
    model = scene.finalize(device=device)
    model.particle_grid = None                   # nor the hash grid rebuilt every substep for it
    solver = newton.solvers.SolverXPBD(model, iterations=settings.iterations)
    states = [model.state(), model.state()]
    control = model.control()

    def substeps() -> None:
        for _ in range(settings.substeps):
            states[0].clear_forces()
            solver.step(states[0], states[1], control, None, h)
            states.reverse()

    graph = None
    if wp.get_device(device).is_cuda and settings.substeps % 2 == 0:   # an even count ends on the state it began
        substeps()                                                      # first call: kernels load outside capture
        with wp.ScopedCapture(device=device) as capture:
            substeps()
        graph = capture.graph

    def frame() -> None:
        if graph is None:
            substeps()
        else:
            wp.capture_launch(graph)
        states[0].particle_q.numpy()
    ms = _median_ms(frame, frames, warmup)
    positions = states[0].particle_q.numpy().reshape(worlds, len(vertices), 3)
    return HangingRun(ms, _checked_stretch(positions, vertices, faces, pins))


def _stable_spring_ke(vertices: np.ndarray, faces: np.ndarray, pins: np.ndarray, density: float, h: float) -> float:
    """The stiffest spring Newton's summed Jacobi corrections keep stable (module docstring): particle masses as
    add_cloth_mesh gives them (a third of each triangle's area times the density), pins weightless."""
    mass = density * lumped_mass(vertices, faces)
    inverse = np.where(mass > 0, 1.0 / np.maximum(mass, 1e-30), 0.0)
    inverse[pins] = 0.0
    edges = unique_edges(faces)
    valence = np.bincount(edges.ravel()).max()
    return float(1.0 / (valence * h * h * (inverse[edges[:, 0]] + inverse[edges[:, 1]]).max()))


def _checked_stretch(positions: np.ndarray, vertices: np.ndarray, faces: np.ndarray, pins: np.ndarray) -> float:
    """The largest edge stretch of (B, V, 3) end positions; RuntimeError unless the run hung the cloth (finite,
    pins where they were, the free vertices lower on average than at rest): a blown-up run's time means nothing."""
    edges = unique_edges(faces)
    rest = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    free = np.setdiff1d(np.arange(len(vertices)), pins)
    if not (np.isfinite(positions).all() and np.allclose(positions[:, pins], vertices[pins], atol=1e-4)
            and (positions[:, free, 1].mean(axis=1) < vertices[free, 1].mean()).all()):
        raise RuntimeError("the run did not hang the cloth (non-finite, pins moved, or nothing fell): its time is "
                           "not comparable")
    return float((np.linalg.norm(positions[:, edges[:, 0]] - positions[:, edges[:, 1]], axis=2) / rest).max())


def _median_ms(frame: Callable[[], None], frames: int, warmup: int) -> float:
    times = []
    for _ in range(warmup + frames):
        start = time.perf_counter()
        frame()
        times.append((time.perf_counter() - start) * 1e3)
    return float(np.median(times[warmup:]))
