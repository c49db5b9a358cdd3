"""A batch of worlds (sim.xpbd.ClothSolver(..., worlds=B)) against the same cloths stepped one by one: every world
has its own body motion, pin targets and harmonic targets, and must move exactly as it does alone."""
import numpy as np
import pytest
import warp as wp

from geometry.harmonics import harmonic_basis
from geometry.loop_subdivision import loop_subdivide
from scenes.grid import first_row_pins, grid_cloth
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, UnstableSimulation, harmonic_constraint
from tests.sim.cloth_checks import coarse_pants_drives, run_worlds

FRAMES = 12
MOTIONS = ("karate", "walk", "rest")


@pytest.fixture(scope="module")
def pants_drives():
    return coarse_pants_drives(FRAMES, MOTIONS)


def run(garment, ids, radii, drives, settings, device="cpu"):
    return run_worlds(garment, ids, radii, drives, settings, FRAMES, device)


@pytest.mark.parametrize("self_collision, spacing", [(True, 8.0), (True, 0.0), (False, 8.0)])
def test_a_batch_moves_each_world_exactly_as_alone(pants_drives, self_collision, spacing, monkeypatch):
    # Spacing 0 puts every world's triangles on top of each other in the shared BVH: then only the world check of
    # the narrow phase keeps the worlds apart (without it this case fails), and the contact lists, sorted by
    # triangle, keep the sums independent of the tree.
    monkeypatch.setattr("sim.xpbd.solver.WORLD_SPACING", spacing)
    garment, ids, radii, drives = pants_drives
    settings = SolverSettings(substeps=2, iterations=10, body_collision=True, self_collision=self_collision)
    batch, solver = run(garment, ids, radii, drives, settings)
    if self_collision:
        assert solver.contacts.vertex_count.numpy().max() > 0  # the batch does exercise self-contact
    assert (solver.capsules.push.numpy() > 0).any()
    for w in range(len(drives)):
        alone, _ = run(garment, ids, radii, drives[w:w + 1], settings)
        np.testing.assert_array_equal(batch[w], alone[0])
    # The worlds differ (else the test could not tell them apart): each moved with its own body.
    assert np.abs(batch[0] - batch[1]).max() > 0.01


def test_harmonic_targets_are_per_world():
    low, low_faces = grid_cloth(0.4, 0.4, 0.15, plane="xy", origin=(0, 1, 0))
    S, faces = loop_subdivide(low, low_faces, levels=2)
    high = S @ low
    basis, _, mass = harmonic_basis(high, faces, int(np.ceil(len(high) / 40)))
    pins = first_row_pins(high, "xy", "corners")
    constraint = harmonic_constraint(basis, mass, pins)
    mass_basis_t = (mass[:, None] * basis).T
    sag = np.array([0.0, -0.05, 0.0]), np.array([0.03, -0.02, 0.04])
    targets = np.stack([mass_basis_t @ (high + d) for d in sag])
    settings = SolverSettings(substeps=2, iterations=10)
    batch = ClothSolver(ClothModel(high, faces, settings, pins, harmonic=constraint), "cpu", worlds=2,
                        initial_inputs=FrameInputs(harmonic_target=targets))
    pin_targets = np.stack([high[pins]] * 2)
    for _ in range(3):
        batch.step(batch.state, FrameInputs(pin_targets=pin_targets, harmonic_target=targets))
    x = batch.state.read_world_positions().astype(np.float64)
    for w in range(2):
        content = mass_basis_t @ x[w]
        assert np.linalg.norm(content - targets[w]) / np.linalg.norm(content) < 1e-5
        alone = ClothSolver(ClothModel(high, faces, settings, pins, harmonic=constraint), "cpu",
                            initial_inputs=FrameInputs(harmonic_target=targets[w]))
        for _ in range(3):
            alone.step(alone.state, FrameInputs(pin_targets=high[pins], harmonic_target=targets[w]))
        np.testing.assert_array_equal(x[w], alone.state.read_positions())


def test_a_blow_up_names_its_world():
    rest, faces = grid_cloth(0.2, 0.2, 0.1, plane="xz")
    solver = ClothSolver(ClothModel(rest, faces, SolverSettings(max_speed=1.0), np.zeros(0, int)), "cpu", worlds=3)
    velocities = np.zeros((3 * len(rest), 3))
    velocities[2 * len(rest):] = [0.0, 5.0, 0.0]   # only the last world is too fast
    solver.state.write_velocities(velocities)
    with pytest.raises(UnstableSimulation, match="world 2, substep 0"):
        solver.step(solver.state)


def test_per_world_inputs_are_checked(pants_drives):
    garment, ids, radii, drives = pants_drives
    settings = SolverSettings(substeps=1, iterations=1, body_collision=True)
    capsules = np.stack([c for c, _ in drives[:2]])
    with pytest.raises(ValueError, match="capsules must be"):
        ClothSolver(ClothModel(garment.vertices, garment.faces, settings, ids, capsule_radii=radii), "cpu", worlds=2,
                    initial_inputs=FrameInputs(capsules=capsules[0, 0]))
    solver = ClothSolver(ClothModel(garment.vertices, garment.faces, settings, ids, capsule_radii=radii), "cpu",
                         worlds=2, initial_inputs=FrameInputs(capsules=capsules[:, 0]))
    with pytest.raises(ValueError, match="pin_targets must have shape"):
        solver.step(solver.state, FrameInputs(pin_targets=drives[0][1][1], capsules=capsules[:, 1]))
    with pytest.raises(ValueError, match="worlds must be"):
        ClothSolver(ClothModel(garment.vertices, garment.faces, settings, ids, capsule_radii=radii), "cpu", worlds=0)


@pytest.mark.skipif(not wp.get_cuda_device_count(), reason="no CUDA device")
@pytest.mark.parametrize("frame_kernel", ["sweeps", "block"])
def test_a_cuda_batch_agrees_with_cuda_alone(pants_drives, frame_kernel):
    garment, ids, radii, drives = pants_drives
    settings = SolverSettings(substeps=2, iterations=10, body_collision=True, self_collision=True,
                              frame_kernel=frame_kernel)
    batch, _ = run(garment, ids, radii, drives, settings, "cuda:0")
    for w in range(len(drives)):
        alone, _ = run(garment, ids, radii, drives[w:w + 1], settings, "cuda:0")
        np.testing.assert_array_equal(batch[w], alone[0])
