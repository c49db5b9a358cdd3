"""Stability of the XPBD solver at the extremes of its settings and inputs (issue 14, item 6).

Every test asserts that positions stay finite and a bound: energy (kinetic + gravitational) never above what the
cloth started with when nothing drives it, edge stretch, a reference computed another way (scipy's static
equilibrium, free fall, the same cloth without the extreme), or the error that ends a run the solver cannot do
(naming frame and substep). The cloth is the hanging 0.6 m square of tests/sim/conftest.py (10 x 10 vertices, top
edge pinned), mostly laid flat at the height of its pins so that it swings down.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize

from geometry.harmonics import harmonic_basis, lumped_mass
from geometry.loop_subdivision import loop_subdivide
from geometry.mesh import unique_edges
from pipeline import scene, simulate
from pipeline.core import cli
from pipeline.artifacts.scene import read_rest_mesh, read_scene_drive
from pipeline.core.config import load_config, resolve_scene, write_settings
from pipeline.solvers.xpbd import solver_settings
from scenes.grid import first_row_pins, grid_cloth
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, UnstableSimulation, cloth_constraints, \
    harmonic_constraint
from cloth_checks import edge_ratios

REPO = Path(__file__).resolve().parents[2]
BASE = {"substeps": 4, "iterations": 20}   # the budget every extreme departs from (test_xpbd's)


@dataclasses.dataclass(frozen=True)
class Trajectory:
    positions: np.ndarray    # (F + 1, V, 3), frame 0 the start
    velocities: np.ndarray   # (F + 1, V, 3)


def simulate_cloth(rest, faces, pins, settings: SolverSettings, frames: int, start=None,
                   pin_targets=None) -> Trajectory:
    """`frames` frames from `start` (default: rest) at zero velocity; `pin_targets(f)` moves the pins (default:
    held where they start)."""
    start = rest if start is None else start
    solver = ClothSolver(ClothModel(rest, faces, settings, pins), "cpu", initial_positions=start)
    x, v = [start.copy()], [np.zeros_like(start)]
    for f in range(1, frames + 1):
        targets = start[pins] if pin_targets is None else pin_targets(f)
        solver.step(solver.state, FrameInputs(pin_targets=targets))
        x.append(solver.state.read_positions())
        v.append(solver.state.read_velocities())
    return Trajectory(np.array(x), np.array(v))


def laid_flat(rest):
    """The hanging cloth turned horizontal about its pinned top edge (y = 1): released, it swings down."""
    start = rest.copy()
    start[:, 2] = rest[:, 1] - 1.0
    start[:, 1] = 1.0
    return start


def energy_over_weight(run: Trajectory, rest, faces, pins, settings: SolverSettings) -> np.ndarray:
    """(F + 1,) kinetic + gravitational energy of the free vertices, divided by their weight (so in metres of
    height). With the pins held and damping >= 0 nothing puts energy in; the elastic energy of soft constraints
    is >= 0, so a solver that makes no energy keeps this at or below its start."""
    mass = settings.density * lumped_mass(rest, faces)
    free = np.ones(len(rest), dtype=bool)
    free[pins] = False
    m = mass[free]
    g = np.asarray(settings.gravity)
    kinetic = 0.5 * np.einsum("v,fvc->f", m, run.velocities[:, free] ** 2)
    potential = -np.einsum("v,fvc,c->f", m, run.positions[:, free], g)
    return (kinetic + potential) / (m.sum() * np.linalg.norm(g))


def max_stretch(run: Trajectory, rest, faces) -> float:
    return max(edge_ratios(x, rest, faces).max() for x in run.positions)


# The extremes of the settings, each with the largest edge stretch it may reach while the flat cloth swings down
# for 0.5 s. Where the solver converges (4 substeps x 20 iterations from 1/1000 s up to 1/60 s frames), hard
# stretch constraints hold to a few per cent; the bounds of the unconverged runs are their measured values
# (2.7 and 7.9) with 25-30 % room: one Jacobi sweep per frame reaches only neighbours, so such a cloth hangs like
# a soft one (test_a_larger_budget_never_stretches_more pins down the trend); the point there is that it stays
# finite and makes no energy. None: the constraints are too soft to bound stretch (see the free-fall test).
EXTREMES = [
    pytest.param({"substeps": 1, "iterations": 1}, 3.5, id="1 substep x 1 iteration"),
    pytest.param({"dt": 1 / 1000}, 1.01, id="dt=1/1000"),
    pytest.param({"dt": 1 / 15}, 1.2, id="dt=1/15"),
    pytest.param({"dt": 1 / 15, "substeps": 1, "iterations": 1}, 10.0, id="dt=1/15, 1 x 1"),
    pytest.param({"stretch_compliance": 0.0, "bending_compliance": 0.0}, 1.05, id="compliance 0"),
    pytest.param({"stretch_compliance": 1e3, "bending_compliance": 1e3}, None, id="compliance 1e3"),
    pytest.param({"density": 1e3}, 1.1, id="heavy (density 1e3)"),
    pytest.param({"density": 1e-4}, 1.05, id="feather-light (density 1e-4)"),
]


@pytest.mark.parametrize("changes, stretch_bound", EXTREMES)
def test_a_released_cloth_makes_no_energy_and_stays_bounded(hanging_cloth, changes, stretch_bound):
    rest, faces, pins = hanging_cloth
    settings = SolverSettings(**{**BASE, **changes})
    run = simulate_cloth(rest, faces, pins, settings, round(0.5 / settings.dt), start=laid_flat(rest))
    assert np.isfinite(run.positions).all() and np.isfinite(run.velocities).all()
    energy = energy_over_weight(run, rest, faces, pins, settings)
    # float32 positions of a ~1 m scene: 1e-6 m of height is the noise floor.
    assert energy.max() <= energy[0] + 1e-6, energy.max() - energy[0]
    assert run.positions[-1, :, 1].min() < 0.9   # it did swing down
    if stretch_bound is not None:
        assert max_stretch(run, rest, faces) <= stretch_bound


@pytest.mark.parametrize("dt", [1 / 60, 1 / 15], ids=["dt=1/60", "dt=1/15"])
def test_a_larger_budget_never_stretches_more(hanging_cloth, dt):
    """Hanging at rest, each budget settles to a steady state (no slow divergence), and a larger budget ends
    less stretched: 1 x 1 hangs 1.9x (1/60 s) and 12x (1/15 s) too long, 4 x 20 within 0.3 % and 4.6 %."""
    rest, faces, pins = hanging_cloth
    budgets = [(1, 1), (1, 4), (1, 20), (4, 20)]
    final = []
    for substeps, iterations in budgets:
        settings = SolverSettings(dt=dt, substeps=substeps, iterations=iterations, damping=3.0)
        run = simulate_cloth(rest, faces, pins, settings, round(6.0 / dt))
        assert np.isfinite(run.positions).all()
        assert np.abs(run.velocities[-1]).max() < 1e-2, (substeps, iterations)          # settled
        final.append(edge_ratios(run.positions[-1], rest, faces).max())
    assert np.all(np.diff(final) < 0), final
    assert final[-1] < 1.1


def test_mass_scale_leaves_a_hard_cloth_unchanged(hanging_cloth):
    """With every compliance 0, XPBD's corrections depend on mass ratios only: a 1e-4 and a 1e4 kg/m^2 cloth
    (10^8 apart) swing exactly as the default one."""
    rest, faces, pins = hanging_cloth
    runs = [simulate_cloth(rest, faces, pins, SolverSettings(**BASE, density=density, stretch_compliance=0.0,
                                                             bending_compliance=0.0), 30, start=laid_flat(rest))
            for density in (0.2, 1e-4, 1e4)]
    for run in runs[1:]:
        assert np.isfinite(run.positions).all()
        np.testing.assert_allclose(run.positions, runs[0].positions, atol=2e-5)


def static_equilibrium(rest, faces, pins, settings: SolverSettings, guess):
    """The positions of least energy sum C^2 / (2 compliance) - m g . x with the pins held (scipy L-BFGS): where
    an XPBD run with soft constraints comes to rest."""
    con = cloth_constraints(rest, faces, settings)
    i, j = con.pairs.T
    mass = settings.density * lumped_mass(rest, faces)
    g = np.asarray(settings.gravity)
    free = np.ones(len(rest), dtype=bool)
    free[pins] = False

    def energy(z):
        x = rest.copy()
        x[free] = z.reshape(-1, 3)
        d = x[i] - x[j]
        length = np.linalg.norm(d, axis=1)
        c = length - np.clip(length, con.rest_min, con.rest_max)
        pull = (c / (con.compliance * length))[:, None] * d
        grad = -mass[:, None] * g
        np.add.at(grad, i, pull)
        np.add.at(grad, j, -pull)
        return np.sum(c * c / (2 * con.compliance)) - np.sum(mass[:, None] * x * g), grad[free].ravel()

    result = minimize(energy, guess[free].ravel(), jac=True, method="L-BFGS-B",
                      options={"maxiter": 20000, "gtol": 1e-12, "ftol": 1e-15})
    assert result.success, result.message
    x = rest.copy()
    x[free] = result.x.reshape(-1, 3)
    return x


@pytest.mark.parametrize("density, tolerance", [(1e3, 0.05), (1e-4, 0.005)], ids=["heavy", "feather-light"])
def test_soft_cloth_comes_to_rest_at_its_static_equilibrium(hanging_cloth, density, tolerance):
    """Stretch compliance 1e-3 m/N: a 1000 kg/m^2 cloth (350 kg) stretches by half under its weight (sags 0.92 m
    instead of 0.6), a 1e-4 kg/m^2 one does not stretch at all. Both come to rest where scipy finds the least
    energy, within `tolerance` of the sag (measured at 4 x 20: 3.2 % and 0.15 %; the gap closes with the budget,
    8 x 75 gives 0.3 %)."""
    rest, faces, pins = hanging_cloth
    settings = SolverSettings(**BASE, density=density, stretch_compliance=1e-3, damping=5.0)
    x = simulate_cloth(rest, faces, pins, settings, 180).positions[-1]
    reference = static_equilibrium(rest, faces, pins, settings, guess=x)
    sag = 1.0 - reference[:, 1].min()
    assert np.isfinite(x).all()
    assert np.abs(x - reference).max() <= tolerance * sag


def test_very_soft_constraints_fall_freely(hanging_cloth):
    """Compliance 1e6 m/N (a spring of 1 micronewton per metre) holds nothing up: every free vertex falls as a
    lone particle under the solver's own integrator, v <- (v + g h) e^(-k h), x <- x + v h, computed here in
    float64. (At 1e3 m/N a 0.7 g vertex still feels the springs: the row below the pins lags free fall by 13 cm.)"""
    rest, faces, pins = hanging_cloth
    settings = SolverSettings(**BASE, stretch_compliance=1e6, bending_compliance=1e6)
    frames = 30
    run = simulate_cloth(rest, faces, pins, settings, frames, start=laid_flat(rest))
    h = settings.dt / settings.substeps
    v = y = 0.0
    for _ in range(frames * settings.substeps):
        v = (v - 9.81 * h) * np.exp(-settings.damping * h)
        y += v * h
    free = np.setdiff1d(np.arange(len(rest)), pins)
    drop = run.positions[-1, free, 1] - run.positions[0, free, 1]
    assert y < -1.0                                      # 0.5 s: a fall of more than a metre
    np.testing.assert_allclose(drop, y, atol=2e-4)       # measured 6e-5
    np.testing.assert_allclose(run.positions[-1, pins], run.positions[0, pins], atol=1e-6)


@pytest.mark.parametrize("substeps, iterations", [(1, 1), (4, 20)])
def test_pins_teleported_a_metre_in_one_frame(hanging_cloth, substeps, iterations):
    """The pinned edge jumps 1 m (along (1, 1, 1)) in frame 5, i.e. at 60 m/s, then holds. The cloth follows:
    free vertices whip to at most twice the pins' speed (measured 1.4x), nothing goes non-finite, and once
    settled the cloth hangs as the same cloth never moved, shifted by the jump (within 5 mm: compression within
    the allowance costs nothing, so a settled cloth may keep a little slack; measured 1.0 mm at 4 x 20).

    max_speed is raised for this: the whip legitimately exceeds the 100 m/s default with more substeps (16 x 20
    reaches 116 m/s and recovers), which the default reports as a blow-up. A jump along the cloth's own plane
    is not used: the cloth then stays exactly planar and an in-plane fold cannot open (stuck at 1.4x stretch)."""
    rest, faces, pins = hanging_cloth
    jump = np.ones(3) / np.sqrt(3.0)
    settings = SolverSettings(substeps=substeps, iterations=iterations, damping=3.0, max_speed=1e3)
    frames = 300
    moved = simulate_cloth(rest, faces, pins, settings, frames,
                           pin_targets=lambda f: rest[pins] + (jump if f >= 5 else 0.0))
    still = simulate_cloth(rest, faces, pins, settings, frames)
    assert np.isfinite(moved.positions).all()
    pin_speed = 1.0 / settings.dt
    free = np.setdiff1d(np.arange(len(rest)), pins)
    assert np.linalg.norm(moved.velocities[:, free], axis=2).max() <= 2.0 * pin_speed
    np.testing.assert_allclose(moved.positions[5:, pins] - jump,
                               np.broadcast_to(rest[pins], (frames - 4, len(pins), 3)), atol=1e-5)
    np.testing.assert_allclose(moved.positions[-1] - jump, still.positions[-1], atol=5e-3)


def test_a_pin_faster_than_max_speed_ends_the_run_with_its_substep(hanging_cloth):
    """The same 1 m jump in a 1/1000 s frame is 1000 m/s, past max_speed: an error naming world and substep (the
    simulate stage adds the frame, see below), not a silently shredded cloth."""
    rest, faces, pins = hanging_cloth
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(**BASE, dt=1 / 1000), pins), "cpu")
    solver.step(solver.state, FrameInputs(pin_targets=rest[pins]))
    with pytest.raises(UnstableSimulation, match="world 0, substep 0"):
        solver.step(solver.state, FrameInputs(pin_targets=rest[pins] + [0.0, 0.0, 1.0]))


def test_non_finite_positions_end_the_run_with_their_substep(hanging_cloth):
    rest, faces, pins = hanging_cloth
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(**BASE), pins), "cpu")
    targets = rest[pins].copy()
    solver.step(solver.state, FrameInputs(pin_targets=targets))
    targets[3] = np.nan   # one pin: NaN reaches its neighbours in the first sweep
    with pytest.raises(UnstableSimulation, match="world 0, substep 0"):
        solver.step(solver.state, FrameInputs(pin_targets=targets))


def test_a_blow_up_in_the_simulate_stage_is_one_error_naming_frame_and_substep(tmp_path, capsys):
    """The patch scene with a max_speed its falling cloth passes after a few frames: `error: <scene.h5>: ...
    at frame F, substep S` (F and S those at which the solver, stepped here by hand, stops), exit status 2, no
    sim_low.h5."""
    settings = resolve_scene(load_config(REPO / "workflow_config.yaml"), "patch", "cpu")
    settings["solver"]["max_speed"] = 0.3
    write_settings(settings, tmp_path / "settings.json")
    scene_path = tmp_path / "scene.h5"
    scene.main([str(tmp_path / "settings.json"), str(scene_path), "--sequence", "train_000"])

    rest, faces = read_rest_mesh(scene_path)
    pins = read_scene_drive(scene_path, body_collision=False).pins
    solver = ClothSolver(ClothModel(rest, faces, solver_settings(settings), pins.ids), "cpu")
    frame = 0
    with pytest.raises(UnstableSimulation) as stopped:
        for frame in range(1, len(pins.targets)):
            solver.step(solver.state, FrameInputs(pin_targets=pins.targets[frame]))
    assert frame > 1   # a later frame than the first, so the count is tested

    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(SystemExit) as exit_info:
        cli.run(simulate.main, ["low", str(tmp_path / "settings.json"), str(scene_path), str(tmp_path / "sim_low.h5"),
                                "--quiet"])
    lines = capsys.readouterr().err.splitlines()
    assert exit_info.value.code == 2
    assert lines == [f"error: {scene_path}: low-res: simulation blew up (NaN or speed > max_speed) at frame {frame}, "
                     f"substep {stopped.value.substep}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def with_sliver_column(rest):
    """The grid with its second column of vertices moved to 1/1000 of the column spacing from the first: the
    quads between them become sliver triangles of aspect ratio 1000."""
    columns = np.unique(rest[:, 0])
    sliver = rest.copy()
    sliver[np.isclose(rest[:, 0], columns[1]), 0] = columns[0] + 1e-3 * (columns[1] - columns[0])
    return sliver


def aspect_ratios(vertices, faces):
    """Longest edge over the height on it, per face."""
    corners = vertices[faces]
    edges = corners - np.roll(corners, 1, axis=1)
    double_area = np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
    return np.linalg.norm(edges, axis=2).max(axis=1) ** 2 / double_area


@pytest.mark.parametrize("substeps, iterations", [(1, 1), (4, 20)])
def test_sliver_triangles_in_the_mesh(hanging_cloth, substeps, iterations):
    """A column of aspect-1000 slivers changes nothing that matters: the cloth swings down with no energy made,
    hangs as high as the regular cloth (4 x 20: 0.2 mm apart, bound 2 mm), its regular edges stretch no more
    than 25 % beyond the regular cloth's, and its 67 micron edges err no more, in metres, than a regular edge
    may (5 % of 67 mm)."""
    rest, faces, pins = hanging_cloth
    sliver = with_sliver_column(rest)
    assert aspect_ratios(sliver, faces).max() >= 1e3 * (1 - 1e-6)
    settings = SolverSettings(substeps=substeps, iterations=iterations)
    runs = [simulate_cloth(mesh, faces, pins, settings, 60, start=laid_flat(mesh)) for mesh in (sliver, rest)]
    assert np.isfinite(runs[0].positions).all()
    energy = energy_over_weight(runs[0], sliver, faces, pins, settings)
    assert energy.max() <= energy[0] + 1e-6
    edges = unique_edges(faces)
    rest_length = np.linalg.norm(sliver[edges[:, 0]] - sliver[edges[:, 1]], axis=1)
    tiny = rest_length < 1e-3
    spacing = rest_length[~tiny].min()
    lengths = np.linalg.norm(runs[0].positions[:, edges[:, 0]] - runs[0].positions[:, edges[:, 1]], axis=2)
    assert (lengths[:, ~tiny] / rest_length[~tiny]).max() <= 1.25 * max_stretch(runs[1], rest, faces)
    if (substeps, iterations) == (4, 20):
        assert (lengths[:, tiny] - rest_length[tiny]).max() <= 0.05 * spacing
        assert abs(runs[0].positions[-1, :, 1].min() - runs[1].positions[-1, :, 1].min()) < 2e-3


@pytest.mark.parametrize("pinned", ["top pair", "one corner"])
def test_a_one_quad_wide_strip(pinned):
    """A 1 m ribbon one quad wide (every vertex on the boundary, the fewest constraints per vertex, so the
    largest Jacobi steps) released flat swings down with no energy made and, damped, hangs straight: its lowest
    point one strip length below the pin (within 2 cm: the strip's width and 1 % stretch)."""
    rest, faces = grid_cloth(0.05, 1.0, 0.1, plane="xy", origin=(0.0, 1.0, 0.0))
    assert len(np.unique(rest[:, 0])) == 2
    top = first_row_pins(rest, "xy", "top_edge")
    pins = top if pinned == "top pair" else top[:1]
    settings = SolverSettings(**BASE, damping=3.0)
    run = simulate_cloth(rest, faces, pins, settings, 240, start=laid_flat(rest))
    assert np.isfinite(run.positions).all()
    energy = energy_over_weight(run, rest, faces, pins, settings)
    assert energy.max() <= energy[0] + 1e-6
    assert max_stretch(run, rest, faces) <= 1.05
    assert np.abs(run.velocities[-1]).max() < 1e-2
    assert abs(run.positions[-1, :, 1].min() - 0.0) < 0.02


@pytest.mark.parametrize("every", ["iteration", "substep"])
def test_a_high_res_run_with_one_harmonic(every):
    """K = 1: the only harmonic is the constant, so the constraint holds the high-res cloth's centre of mass to
    the subdivided low-res cloth's, and nothing else. The run stays finite, keeps its edges and holds that
    centre (checked as a centre of mass, without the basis) on every frame."""
    low, low_faces = grid_cloth(0.4, 0.4, 0.15, plane="xy", origin=(0, 1, 0))
    S, faces = loop_subdivide(low, low_faces, levels=2)
    high = S @ low
    low_pins = first_row_pins(low, "xy", "corners")
    settings = SolverSettings(**BASE, harmonic_every=every)
    # The low-res cloth released flat: its centre of mass falls and swings, which the high-res run must follow.
    low_run = simulate_cloth(low, low_faces, low_pins, settings, 20, start=laid_flat(low))
    basis, _, mass = harmonic_basis(high, faces, 1)
    assert np.ptp(basis) < 1e-6 * np.abs(basis).max()          # the constant function
    pins = first_row_pins(high, "xy", "corners")
    targets = np.einsum("vk,v,fvc->fkc", basis, mass, np.stack([S @ x for x in low_run.positions]))
    start = S @ low_run.positions[0]
    solver = ClothSolver(ClothModel(high, faces, settings, pins, harmonic=harmonic_constraint(basis, mass, pins)),
                         "cpu", initial_inputs=FrameInputs(harmonic_target=targets[0]), initial_positions=start)
    for f in range(1, len(targets)):
        solver.step(solver.state, FrameInputs(pin_targets=start[pins], harmonic_target=targets[f]))
        x = solver.state.read_positions()
        assert np.isfinite(x).all()
        centre = np.average(x, axis=0, weights=mass)
        np.testing.assert_allclose(centre, np.average(S @ low_run.positions[f], axis=0, weights=mass), atol=1e-5)
    assert edge_ratios(x, high, faces).max() < 1.05
