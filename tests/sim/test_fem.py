"""The quasi-static FEM solver (sim.fem): the stable Neo-Hookean energy, its gradient and Hessian against finite
differences and a numpy implementation, the patch test, rest, extreme bone motion, convergence, batching and the
devices."""
import numpy as np
import pytest
import scipy.sparse as sp
import warp as wp
from scipy.spatial.transform import Rotation

from geometry.tets import kuhn_grid, tet_volumes
from sim.fem import ElasticEnergy, FemInputs, FemModel, FemSettings, FemSolver
from sim.solver import UnstableSimulation
from sim.fem.neohookean import mat99d, stress_derivative
from tests.sim import fem_reference as ref

CPU = wp.get_device("cpu")


def solved_nodes(model: FemModel, inputs: FemInputs, device: str = "cpu") -> np.ndarray:
    """One frame of `model` from rest on `device`, checked converged: its nodes."""
    solver = FemSolver(model, device)
    solver.step(solver.state, inputs)
    assert solver.last_report.converged.all()
    return solver.state.read_nodes()[0]


def beam(cells=(8, 2, 2), length=4.0):
    """A beam along x, 1 unit square section, its two end faces driven: nodes, tets, driven ids, which are at the
    far end."""
    spacing = length / cells[0]
    nodes, tets = kuhn_grid(cells, np.zeros(3), spacing)
    nodes[:, 1:] *= 1.0 / (spacing * cells[1])
    driven = np.flatnonzero((nodes[:, 0] < 1e-9) | (nodes[:, 0] > length - 1e-9))
    return nodes, tets, driven, nodes[driven, 0] > length / 2


def rotated_about(points, degrees, axis, centre):
    R = Rotation.from_euler(axis, degrees, degrees=True).as_matrix()
    return (points - centre) @ R.T + centre


def vec3d(a):
    return wp.array(np.ascontiguousarray(a, dtype=np.float64), dtype=wp.vec3d, device=CPU)


def dense_hessian(energy: ElasticEnergy, nodes: np.ndarray, project: bool) -> np.ndarray:
    H = energy.assemble_hessian(vec3d(nodes), project=project)
    values = H.values.numpy()[: H.nnz_sync()]
    rows = H.offsets.numpy()
    return sp.bsr_matrix((values, H.columns.numpy()[: len(values)], rows), shape=H.shape).toarray()


@pytest.fixture(scope="module")
def cube():
    """2 x 2 x 2 cells of side 0.5, one corner driven, and a deformed state with an inverted tet among stretched,
    sheared and compressed ones."""
    nodes, tets = kuhn_grid((2, 2, 2), np.zeros(3), 0.5)
    model = FemModel(nodes, tets, FemSettings(youngs_modulus=1000.0, poisson_ratio=0.4), driven=np.array([0]))
    deformed = nodes @ np.array([[1.2, 0.3, 0.0], [0.0, 0.7, 0.1], [0.1, 0.0, 0.9]]).T
    deformed += 0.08 * np.random.default_rng(3).standard_normal(nodes.shape)
    deformed[tets[5, 0]], deformed[tets[5, 1]] = deformed[tets[5, 1]].copy(), deformed[tets[5, 0]].copy()
    assert (tet_volumes(deformed, tets) < 0).any()
    return model, ElasticEnergy(model, CPU, 1), deformed


def test_energy_and_gradient_match_a_numpy_implementation_and_finite_differences(cube):
    model, energy, x = cube
    mu, lam = model.settings.lame
    e, g = wp.zeros(1, dtype=wp.float64, device=CPU), wp.zeros(len(x), dtype=wp.vec3d, device=CPU)
    energy.energy(vec3d(x), e)
    energy.gradient(vec3d(x), g)
    assert e.numpy()[0] == pytest.approx(ref.energy(x, model.rest_vertices, model.tets, mu, lam), rel=1e-12)
    expected = ref.gradient(x, model.rest_vertices, model.tets, mu, lam)
    expected[model.driven] = 0.0
    np.testing.assert_allclose(g.numpy(), expected, atol=1e-9 * np.abs(expected).max())
    h = 1e-6
    inverted_corner = next(n for n in model.tets[5] if n not in model.driven)
    for node, axis in [(4, 0), (13, 1), (26, 2), (inverted_corner, 2)]:
        plus, minus = x.copy(), x.copy()
        plus[node, axis] += h
        minus[node, axis] -= h
        fd = (ref.energy(plus, model.rest_vertices, model.tets, mu, lam)
              - ref.energy(minus, model.rest_vertices, model.tets, mu, lam)) / (2 * h)
        assert g.numpy()[node, axis] == pytest.approx(fd, rel=1e-6, abs=1e-6 * np.abs(expected).max())


def test_hessian_vector_products_match_finite_differences_of_the_gradient(cube):
    model, energy, x = cube
    mu, lam = model.settings.lame
    H = dense_hessian(energy, x, project=False)
    rng = np.random.default_rng(7)
    free = np.setdiff1d(np.arange(len(x)), model.driven)
    for _ in range(3):
        v = rng.standard_normal(x.shape)
        v[model.driven] = 0.0
        h = 1e-6
        fd = (ref.gradient(x + h * v, model.rest_vertices, model.tets, mu, lam)
              - ref.gradient(x - h * v, model.rest_vertices, model.tets, mu, lam)) / (2 * h)
        Hv = (H @ v.ravel()).reshape(-1, 3)
        np.testing.assert_allclose(Hv[free], fd[free], rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    # Driven nodes' rows and columns are the identity's.
    rows = (3 * model.driven[:, None] + np.arange(3)).ravel()
    np.testing.assert_array_equal(H[rows][:, rows], np.eye(len(rows)))
    np.testing.assert_array_equal(H[rows][:, np.setdiff1d(np.arange(3 * len(x)), rows)], 0.0)


@wp.kernel
def _stress_derivatives(F: wp.array(dtype=wp.mat33d), mu: wp.float64, lam: wp.float64, project: bool,
                        out: wp.array(dtype=mat99d)):
    i = wp.tid()
    out[i] = stress_derivative(F[i], mu, lam, project)


def reference_stress(F, mu, lam):
    J = np.linalg.det(F)
    return mu * F + (lam * (J - 1) - mu) * J * np.linalg.inv(F).T


def test_the_stress_derivative_and_its_projection_match_finite_differences_and_a_numpy_eigensolver():
    mu, lam = FemSettings().lame
    rng = np.random.default_rng(5)
    R = Rotation.from_euler("xyz", [30, 10, -70], degrees=True).as_matrix()
    Fs = [np.eye(3), R, R @ np.diag([1.3, 0.9, 0.6]), np.diag([0.5, 0.5, 0.5]), np.diag([1.4, 1.2, 1.1]),
          np.diag([1.0, 0.8, -0.3]) @ R, np.eye(3) + 0.4 * rng.standard_normal((3, 3)),
          np.diag([1.0, 1.0, 1.0 + 1e-9])]                      # repeated singular values
    out = wp.zeros(len(Fs), dtype=mat99d, device=CPU)
    for project in (False, True):
        wp.launch(_stress_derivatives, dim=len(Fs), inputs=[wp.array(np.array(Fs), dtype=wp.mat33d, device=CPU), mu,
                                                            lam, project, out], device=CPU)
        for F, H in zip(Fs, out.numpy()):
            h = 1e-6
            fd = np.stack([((reference_stress(F + h * E, mu, lam) - reference_stress(F - h * E, mu, lam)) / (2 * h))
                           .ravel() for E in np.eye(9).reshape(9, 3, 3)], 1)
            if project:
                values, vectors = np.linalg.eigh(0.5 * (fd + fd.T))
                fd = vectors @ np.diag(np.maximum(values, 0.0)) @ vectors.T
            np.testing.assert_allclose(H, fd, atol=1e-5 * np.abs(fd).max() + 1e-9 * mu)


def test_the_projected_hessian_is_positive_semi_definite_where_the_exact_one_is_not(cube):
    model, energy, x = cube
    exact = dense_hessian(energy, x, project=False)
    projected = dense_hessian(energy, x, project=True)
    assert np.linalg.eigvalsh(exact).min() < -1e-3 * np.abs(exact).max()
    assert np.linalg.eigvalsh(projected).min() > -1e-9 * np.abs(projected).max()
    np.testing.assert_allclose(projected, projected.T, atol=1e-9 * np.abs(projected).max())


@pytest.mark.parametrize("degrees", [0.0, 73.0])
def test_rest_and_any_rotation_of_it_have_zero_energy_and_force(cube, degrees):
    model, energy, _ = cube
    x = rotated_about(model.rest_vertices, degrees, "xyz"[1], np.array([0.3, 0.2, 0.1])) + np.array([5.0, -2, 1])
    e, g = wp.zeros(1, dtype=wp.float64, device=CPU), wp.zeros(len(x), dtype=wp.vec3d, device=CPU)
    energy.energy(vec3d(x), e)
    energy.gradient(vec3d(x), g)
    mu = model.settings.lame[0]
    assert abs(e.numpy()[0]) < 1e-12 * mu
    assert np.abs(g.numpy()).max() < 1e-12 * mu


def test_an_affine_deformation_of_the_boundary_is_reproduced_inside_the_patch_test():
    nodes, tets = kuhn_grid((3, 3, 3), np.zeros(3), 1.0 / 3)
    boundary = np.flatnonzero(((nodes < 1e-9) | (nodes > 1 - 1e-9)).any(axis=1))
    inside = np.setdiff1d(np.arange(len(nodes)), boundary)
    A = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix() @ np.array(
        [[1.3, 0.2, 0.0], [0.0, 0.8, -0.15], [0.05, 0.0, 1.1]])
    affine = nodes @ A.T + np.array([0.4, -1.0, 2.0])
    # The surface embedded in the tets must follow the same map: points anywhere in the cube.
    points = np.random.default_rng(0).uniform(0.02, 0.98, (20, 3))
    tet_of, weights = embed_points(nodes, tets, points)
    model = FemModel(nodes, tets, FemSettings(), driven=boundary, embedding=(tet_of, weights))
    solver = FemSolver(model, "cpu")
    solver.step(solver.state, FemInputs(affine[boundary]))
    assert solver.last_report.converged.all()
    np.testing.assert_allclose(solver.state.read_nodes()[0][inside], affine[inside], atol=1e-9)
    np.testing.assert_allclose(solver.state.read_world_positions()[0], points @ A.T + np.array([0.4, -1.0, 2.0]),
                               atol=1e-5)


def embed_points(nodes, tets, points):
    """The tet holding each point and its barycentric weights (brute force: tests' meshes are small)."""
    Dm = np.transpose(nodes[tets[:, 1:]] - nodes[tets[:, :1]], (0, 2, 1))
    lam = np.einsum("tij,ptj->pti", np.linalg.inv(Dm), points[:, None] - nodes[tets[:, 0]][None])
    weights = np.concatenate([1 - lam.sum(axis=2, keepdims=True), lam], axis=2)
    tet_of = weights.min(axis=2).argmax(axis=1)
    return tet_of, weights[np.arange(len(points)), tet_of]


def solve_twist_and_bend(settings, frames, degrees):
    """The beam's far end turned `degrees` about its axis and bent as far about z, in `frames` equal frames."""
    nodes, tets, driven, far = beam()
    solver = FemSolver(FemModel(nodes, tets, settings, driven), "cpu")
    reports, targets = [], nodes[driven].copy()
    for f in range(1, frames + 1):
        end = rotated_about(nodes[driven][far], degrees * f / frames, "x", np.array([4.0, 0.5, 0.5]))
        targets[far] = rotated_about(end, degrees * f / frames, "z", np.array([2.0, 0.5, 0.5]))
        solver.step(solver.state, FemInputs(targets))
        reports.append(solver.last_report)
    return solver, reports, nodes, tets, driven


def test_each_frame_reaches_its_residual_tolerance_and_no_element_inverts_under_extreme_motion():
    settings = FemSettings(residual_tolerance=1e-7)
    solver, reports, nodes, tets, driven = solve_twist_and_bend(settings, frames=10, degrees=150.0)
    assert all(r.converged.all() and (r.residual <= 1e-7).all() for r in reports)
    x = solver.state.read_nodes()[0]
    assert tet_volumes(x, tets).min() > 0.05 * tet_volumes(nodes, tets).min()
    # The residual the solver reports is the one a numpy implementation finds there.
    mu, lam = settings.lame
    g = ref.gradient(x, nodes, tets, mu, lam)
    g[driven] = 0.0
    assert np.linalg.norm(g, axis=1).max() * solver.residual_scale == pytest.approx(reports[-1].residual[0], rel=1e-3)


def test_worlds_stepped_together_are_the_worlds_stepped_alone():
    nodes, tets, driven, far = beam((4, 1, 1))
    model = FemModel(nodes, tets, FemSettings(), driven)
    targets = [nodes[driven].copy() for _ in range(2)]
    targets[0][far] = rotated_about(targets[0][far], 40.0, "x", np.array([4.0, 0.5, 0.5]))
    targets[1][far] += np.array([0.3, 0.8, 0.0])
    together = FemSolver(model, "cpu", worlds=2)
    together.step(together.state, FemInputs(np.stack(targets)))
    for w in range(2):
        alone = FemSolver(model, "cpu")
        alone.step(alone.state, FemInputs(targets[w]))
        np.testing.assert_allclose(together.state.read_nodes()[w], alone.state.read_nodes()[0], atol=1e-6)
    assert together.last_report.converged.all()


@pytest.mark.parametrize("change, message", [
    (dict(tets=np.array([[0, 2, 1, 3]])), "inverted or degenerate"),
    (dict(tets=np.array([[0, 1, 2, 9]])), "tets must be"),
    (dict(driven=np.zeros(0, dtype=int)), "driven must be"),
    (dict(driven=np.array([0, 0])), "driven must be"),
    (dict(rest_vertices=np.vstack([[0, 0, 0], np.eye(3), [5, 5, 5]])), "belong to no tet"),
    (dict(embedding=(np.array([1]), np.array([[0.25] * 4]))), "embedding tet ids"),
    (dict(embedding=(np.array([0]), np.array([[0.5] * 4]))), "sum to 1"),
], ids=lambda value: value if isinstance(value, str) else None)
def test_a_model_that_does_not_fit_is_refused_naming_the_field(change, message):
    fields = dict(rest_vertices=np.vstack([[0, 0, 0], np.eye(3)]), tets=np.array([[0, 1, 2, 3]]),
                  driven=np.array([0]))
    with pytest.raises(ValueError, match=message):
        FemModel(**{**fields, **change})


@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device on this machine")
def test_cpu_and_cuda_agree():
    nodes, tets, driven, far = beam()
    model = FemModel(nodes, tets, FemSettings(residual_tolerance=1e-8), driven)
    targets = nodes[driven].copy()
    targets[far] = rotated_about(targets[far], 60.0, "x", np.array([4.0, 0.5, 0.5]))
    results = [solved_nodes(model, FemInputs(targets), device) for device in ("cpu", "cuda:0")]
    np.testing.assert_allclose(results[0], results[1], atol=1e-6)


def test_load_steps_reach_the_same_minimum_as_one_step():
    nodes, tets, driven, far = beam((4, 1, 1))
    targets = nodes[driven].copy()
    targets[far] = rotated_about(targets[far], 50.0, "x", np.array([4.0, 0.5, 0.5]))
    results = [solved_nodes(FemModel(nodes, tets, FemSettings(load_steps=load_steps, residual_tolerance=1e-9), driven),
                            FemInputs(targets)) for load_steps in (1, 3)]
    np.testing.assert_allclose(results[0], results[1], atol=1e-7)


def test_a_motion_guess_changes_where_newton_starts_not_where_it_ends():
    nodes, tets, driven, far = beam((4, 1, 1))
    model = FemModel(nodes, tets, FemSettings(residual_tolerance=1e-9), driven)
    targets = nodes[driven].copy()
    targets[far] += np.array([0.0, 1.0, 0.0])
    guess = np.outer(nodes[:, 0] / 4.0, [0.0, 1.0, 0.0])         # the beam sheared along with its end
    ends = [solved_nodes(model, FemInputs(targets, motion)) for motion in (None, guess)]
    np.testing.assert_allclose(ends[0], ends[1], atol=1e-7)


@pytest.mark.parametrize("inputs, message", [
    (lambda d: FemInputs(np.zeros((d + 1, 3))), "driven_targets must be"),
    (lambda d: FemInputs(np.full((d, 3), np.nan)), "driven_targets must be"),
    (lambda d: FemInputs(np.zeros((d, 3)), np.zeros((3, 3))), "node_motion must be"),
], ids=["shape", "nan", "motion"])
def test_inputs_that_do_not_fit_are_refused(inputs, message):
    nodes, tets, driven, _ = beam((2, 1, 1))
    solver = FemSolver(FemModel(nodes, tets, FemSettings(), driven), "cpu")
    with pytest.raises(ValueError, match=message):
        solver.step(solver.state, inputs(len(driven)))


def test_forces_that_overflow_are_an_unstable_simulation_naming_the_world():
    nodes, tets, driven, far = beam((2, 1, 1))
    solver = FemSolver(FemModel(nodes, tets, FemSettings(), driven), "cpu", worlds=2)
    targets = np.stack([nodes[driven], nodes[driven]])
    targets[1][far] *= 1e200
    with pytest.raises(UnstableSimulation) as caught:
        solver.step(solver.state, FemInputs(targets))
    assert caught.value.world == 1
