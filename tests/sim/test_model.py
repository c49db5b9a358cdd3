"""The cloth's static model (sim.xpbd.ClothModel): what it refuses, and that it stays what it was built as while the
solvers built from it step."""
import numpy as np
import pytest

from geometry.harmonics import harmonic_basis
from sim.xpbd import ClothModel, ClothSolver, FrameInputs, SolverSettings, harmonic_constraint

BODY = SolverSettings(substeps=1, iterations=2, body_collision=True)


@pytest.mark.parametrize("change, message", [
    (dict(rest_vertices=np.zeros((9, 2))), "rest_vertices must be"),
    (dict(rest_vertices=np.full((9, 3), np.nan)), "rest_vertices must be"),
    (dict(faces=np.array([[0, 1, 9]])), "faces must be"),
    (dict(faces=np.array([[0, 1, -1]])), "faces must be"),
    (dict(faces=np.array([[0.0, 1.0, 2.0]])), "faces must be"),
    (dict(pinned=np.array([9])), "pinned must be"),
    (dict(pinned=np.array([-1])), "pinned must be"),
    (dict(pinned=np.array([1.0])), "pinned must be"),
    (dict(pinned=np.array([[1]])), "pinned must be"),
    (dict(settings=BODY), "body_collision needs capsules"),
    (dict(capsule_radii=np.array([[0.1, 0.1]])), "body_collision is off"),
    (dict(settings=BODY, capsule_radii=np.array([[0.1, 0.1, 0.1]])), "capsule_radii must be"),
    (dict(settings=BODY, capsule_radii=np.full((256, 2), 0.1)), "N <= 255"),
    (dict(settings=BODY, capsule_radii=np.array([[0.1, 0.0]])), "finite and positive"),
], ids=lambda value: value if isinstance(value, str) else None)
def test_a_model_that_does_not_fit_is_refused_naming_the_field(hanging_cloth, change, message):
    rest, faces, pins = hanging_cloth
    fields = dict(rest_vertices=rest[:9], faces=np.array([[0, 1, 3], [1, 4, 3]]), settings=SolverSettings(),
                  pinned=np.array([0, 1]))
    with pytest.raises(ValueError, match=message):
        ClothModel(**{**fields, **change})


def test_a_harmonic_constraint_of_another_mesh_is_refused(hanging_cloth):
    rest, faces, pins = hanging_cloth
    basis, _, mass = harmonic_basis(rest, faces, 3)
    constraint = harmonic_constraint(basis, mass, pins)
    ClothModel(rest, faces, SolverSettings(), pins, harmonic=constraint)
    fewer = len(rest) - 1          # the mesh less its last vertex
    with pytest.raises(ValueError, match=rf"bases must both be \(V, K\) with V = {fewer}"):
        ClothModel(rest[:fewer], faces[(faces < fewer).all(axis=1)], SolverSettings(), pins, harmonic=constraint)


def test_the_pins_start_where_the_state_does_not_in_the_first_inputs(hanging_cloth):
    rest, faces, pins = hanging_cloth
    with pytest.raises(ValueError, match="takes no pin_targets"):
        ClothSolver(ClothModel(rest, faces, SolverSettings(), pins), "cpu",
                    initial_inputs=FrameInputs(pin_targets=rest[pins]))


def test_solvers_of_one_model_step_alike_and_leave_it_as_it_was(hanging_cloth):
    """A model is static: two solvers built from one model (one stepped before the other is built) move the cloth
    the same, bit for bit, and the model's arrays are what they were."""
    rest, faces, pins = hanging_cloth
    radii = [[0.05, 0.04]]
    capsule = np.array([[[0.2, 0.8, -0.1], [0.4, 0.8, 0.1]]])
    model = ClothModel(rest, faces, SolverSettings(substeps=2, iterations=5, body_collision=True), pins,
                       capsule_radii=radii)
    kept = [model.rest_vertices.copy(), model.faces.copy(), model.pinned.copy(), model.capsule_radii.copy()]
    assert model.pinned.dtype == np.int64 and model.capsule_radii.dtype == np.float64
    runs = []
    for _ in range(2):
        solver = ClothSolver(model, "cpu", initial_inputs=FrameInputs(capsules=capsule))
        for f in range(1, 6):
            solver.step(solver.state, FrameInputs(pin_targets=rest[pins] + [0.01 * f, 0.0, 0.0], capsules=capsule))
        runs.append(solver.state.read_positions())
    assert np.abs(runs[0] - rest).max() > 1e-3           # the cloth did move
    np.testing.assert_array_equal(runs[0], runs[1])
    for before, after in zip(kept, [model.rest_vertices, model.faces, model.pinned, model.capsule_radii]):
        np.testing.assert_array_equal(before, after)
