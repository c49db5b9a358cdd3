"""Physics of the XPBD solver: settling, energy, stability at the extremes, the harmonic constraint."""
import numpy as np
import pytest

from scenes.grid import first_row_pins, grid_cloth
from geometry.harmonics import harmonic_basis, lumped_mass
from geometry.loop_subdivision import loop_subdivide
from geometry.mesh import unique_edges
from sim.xpbd import (ClothModel, ClothSolver, FrameInputs, SolverSettings, UnstableSimulation, cloth_constraints,
                      harmonic_constraint)
from cloth_checks import edge_ratios


def test_pinned_hanging_cloth_settles(hanging_cloth):
    rest, faces, pins = hanging_cloth
    # Start sideways (flat, horizontal) so the cloth has to swing down and come to rest.
    start = rest.copy()
    start[:, 2] = rest[:, 1] - 1.0
    start[:, 1] = 1.0
    settings = SolverSettings(substeps=8, iterations=30, damping=4.0)
    solver = ClothSolver(ClothModel(rest, faces, settings, pins), "cpu", initial_positions=start)
    for _ in range(300):
        solver.step(solver.state, FrameInputs(pin_targets=start[pins]))
    x = solver.state.read_positions()
    assert np.abs(solver.state.read_velocities()).max() < 1e-2
    ratios = edge_ratios(x, rest, faces)
    assert ratios.max() <= 1.01
    assert ratios.min() >= 0.75 - 1e-4
    # It hangs: everything below the pinned row, the free edge about one cloth length down.
    assert x[:, 1].max() <= 1.0 + 1e-5
    assert x[:, 1].min() < 1.0 - 0.5


def test_pins_follow_their_targets(hanging_cloth):
    rest, faces, pins = hanging_cloth
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(substeps=2, iterations=5), pins), "cpu")
    target = rest[pins] + np.array([0.1, 0.0, -0.05])
    solver.step(solver.state, FrameInputs(pin_targets=target))
    np.testing.assert_allclose(solver.state.read_positions()[pins], target, atol=1e-6)


def test_kinetic_energy_never_grows_without_damping_or_forces():
    rest, faces = grid_cloth(0.5, 0.5, 0.12, plane="xz")
    rng = np.random.default_rng(3)
    # Hard stretch constraints store no potential energy (soft bending would, and trade it with kinetic energy),
    # so any kinetic energy gained would be made by the solver.
    settings = SolverSettings(substeps=4, iterations=20, damping=0.0, gravity=(0.0, 0.0, 0.0),
                              stretch_compliance=0.0, bending=False)
    solver = ClothSolver(ClothModel(rest, faces, settings, np.zeros(0, int)), "cpu")
    solver.state.write_velocities(rng.normal(scale=0.5, size=rest.shape))
    mass = lumped_mass(rest, faces)
    energies = []
    for _ in range(30):
        solver.step(solver.state)
        energies.append(0.5 * np.sum(mass[:, None] * solver.state.read_velocities() ** 2))
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= 1e-6 * energies[0])


def test_momentum_is_conserved_by_the_constraints():
    rest, faces = grid_cloth(0.4, 0.4, 0.1, plane="xz")
    settings = SolverSettings(substeps=2, iterations=10, damping=0.0, gravity=(0.0, 0.0, 0.0))
    solver = ClothSolver(ClothModel(rest, faces, settings, np.zeros(0, int)), "cpu")
    rng = np.random.default_rng(0)
    solver.state.write_velocities(rng.normal(size=rest.shape))
    mass = lumped_mass(rest, faces)
    before = (mass[:, None] * solver.state.read_velocities()).sum(axis=0)
    for _ in range(5):
        solver.step(solver.state)
    after = (mass[:, None] * solver.state.read_velocities()).sum(axis=0)
    np.testing.assert_allclose(after, before, atol=1e-4 * np.abs(before).max())


def test_compression_is_free_down_to_the_allowance():
    rest, faces = grid_cloth(0.3, 0.3, 0.2, plane="xz")
    settings = SolverSettings(bending=False, compression_allowance=0.75)
    con = cloth_constraints(rest, faces, settings)
    np.testing.assert_allclose(con.rest_min, 0.75 * con.rest_max)
    # Squash the cloth to 85 % along x: within the allowance, so nothing moves.
    squashed = rest * np.array([0.85, 1.0, 1.0])
    no_gravity = SolverSettings(bending=False, gravity=(0.0, 0.0, 0.0), substeps=2, iterations=20)
    solver = ClothSolver(ClothModel(rest, faces, no_gravity, np.zeros(0, int)), "cpu", initial_positions=squashed)
    solver.step(solver.state)
    np.testing.assert_allclose(solver.state.read_positions(), squashed, atol=1e-6)
    # Squash to 50 %: edges come back to at least 75 %.
    solver = ClothSolver(ClothModel(rest, faces, no_gravity, np.zeros(0, int)), "cpu",
                         initial_positions=rest * [0.5, 1, 1])
    for _ in range(10):
        solver.step(solver.state)
    assert edge_ratios(solver.state.read_positions(), rest, faces).min() > 0.74


def test_bending_switch_removes_bending_links():
    rest, faces = grid_cloth(0.3, 0.3, 0.2, plane="xz")
    with_bending = cloth_constraints(rest, faces, SolverSettings(bending=True))
    without = cloth_constraints(rest, faces, SolverSettings(bending=False))
    assert len(without.pairs) == len(unique_edges(faces))
    assert len(with_bending.pairs) > len(without.pairs)


@pytest.mark.parametrize("changes", [
    dict(dt=1 / 30), dict(dt=1 / 600), dict(substeps=1), dict(substeps=64, iterations=5), dict(iterations=1),
    dict(iterations=200, substeps=2), dict(stretch_compliance=0.0, bending_compliance=0.0),
    dict(stretch_compliance=10.0, bending_compliance=10.0),
], ids=lambda c: ",".join(f"{k}={v:.3g}" for k, v in c.items()))
def test_stable_at_the_extremes(changes):
    rest, faces = grid_cloth(0.5, 0.5, 0.2, plane="xz", origin=(0, 1, 0))  # a 2x2-ish patch
    pins = first_row_pins(rest, "xz", "corners")
    settings = SolverSettings(**{"substeps": 4, "iterations": 20, **changes})
    solver = ClothSolver(ClothModel(rest, faces, settings, pins), "cpu")
    for _ in range(20):
        solver.step(solver.state, FrameInputs(pin_targets=rest[pins]))
    x = solver.state.read_positions()
    assert np.isfinite(x).all()
    ratios = edge_ratios(x, rest, faces)
    # Bounded constraint error: even the softest, fewest-iteration runs stay within a factor of the rest length.
    assert ratios.max() < (10.0 if changes.get("stretch_compliance", 0) > 1 else 1.5)
    assert ratios.min() > 0.5


def test_sliver_triangle_stays_finite():
    rest = np.array([[0, 1, 0], [1, 1, 0], [0.5, 1, 1e-4], [0.5, 1, -1.0]], float)
    faces = np.array([[0, 2, 1], [0, 1, 3]])
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(substeps=8, iterations=75), np.array([3])), "cpu")
    for _ in range(30):
        solver.step(solver.state, FrameInputs(pin_targets=rest[[3]]))
    assert np.isfinite(solver.state.read_positions()).all()


def test_blow_up_is_reported_with_its_substep():
    rest, faces = grid_cloth(0.3, 0.3, 0.2, plane="xz")
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(substeps=4, iterations=2, max_speed=1.0),
                                    np.zeros(0, int)), "cpu")
    solver.state.write_velocities(np.full(rest.shape, 50.0))
    with pytest.raises(UnstableSimulation, match="substep 0"):
        solver.step(solver.state)


def test_settings_out_of_range_are_rejected():
    with pytest.raises(ValueError, match="relaxation"):
        SolverSettings(relaxation=2.5)
    with pytest.raises(ValueError, match="substeps"):
        SolverSettings(substeps=0)


@pytest.mark.parametrize("every", ["iteration", "substep"])
def test_harmonic_constraint_holds_the_high_res_run_to_the_low_res_one(every):
    low, low_faces = grid_cloth(0.4, 0.4, 0.15, plane="xy", origin=(0, 1, 0))
    S, faces = loop_subdivide(low, low_faces, levels=2)
    high = S @ low
    basis, _, mass = harmonic_basis(high, faces, int(np.ceil(len(high) / 40)))
    pins = first_row_pins(high, "xy", "corners")
    constraint = harmonic_constraint(basis, mass, pins)
    # Orthonormality makes the projection exact: the residual of B^T M (x + A r) vanishes for any x.
    rng = np.random.default_rng(1)
    x = rng.normal(size=high.shape)
    r = (mass[:, None] * basis).T @ x
    projected = x - constraint.correction_basis @ r
    np.testing.assert_allclose((mass[:, None] * basis).T @ projected, 0, atol=1e-9)
    np.testing.assert_array_equal(projected[pins], x[pins])

    # A target that the low-res cloth would give after sagging 5 cm: the high-res run must match it.
    target_positions = high + np.array([0.0, -0.05, 0.0])
    target = (mass[:, None] * basis).T @ target_positions
    model = ClothModel(high, faces, SolverSettings(substeps=2, iterations=10, harmonic_every=every), pins,
                       harmonic=constraint)
    solver = ClothSolver(model, "cpu", initial_inputs=FrameInputs(harmonic_target=target))
    for _ in range(3):
        solver.step(solver.state, FrameInputs(pin_targets=high[pins], harmonic_target=target))
    content = (mass[:, None] * basis).T @ solver.state.read_positions()
    assert np.linalg.norm(content - target) / np.linalg.norm(content) < 1e-5


def test_a_solver_steps_only_the_state_it_made():
    rest, faces = grid_cloth(0.2, 0.2, 0.1, plane="xz")
    settings = SolverSettings(substeps=1, iterations=1)
    solver = ClothSolver(ClothModel(rest, faces, settings, np.zeros(0, int)), "cpu")
    other = ClothSolver(ClothModel(rest, faces, settings, np.zeros(0, int)), "cpu").state
    with pytest.raises(ValueError, match="state it made"):
        solver.step(other)


def test_reads_are_copies_that_stepping_leaves_alone(hanging_cloth):
    # On the CPU device a Warp array's numpy() is a view of the live array: a read kept across steps must not be.
    rest, faces, pins = hanging_cloth
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(substeps=1, iterations=2), pins), "cpu")
    reads = [solver.state.read_world_positions(), solver.state.read_positions(), solver.state.read_velocities()]
    kept = [r.copy() for r in reads]
    solver.step(solver.state, FrameInputs(pin_targets=rest[pins]))
    assert np.abs(solver.state.read_positions() - kept[1]).max() > 1e-4   # the cloth did move
    for read, before in zip(reads, kept):
        np.testing.assert_array_equal(read, before)
