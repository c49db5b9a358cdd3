"""The solver stores vertices in the mesh's locality order (geometry.mesh.locality_order) and shows the caller its
own order: the same motion as stored in the caller's order (bit for bit where each vertex's sums keep their order),
state reads and writes in the caller's order, and reads that are copies."""
import numpy as np
import pytest

from geometry.harmonics import harmonic_basis, harmonic_count
from geometry.loop_subdivision import loop_subdivide
from geometry.mesh import inverse_order, locality_order, unique_edges
from scenes.capsules import capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.motion import body_state, make_motion
from scenes.skeleton import default_skeleton
from scenes.skinning import linear_blend_skinning
from sim.xpbd import ClothSolver, FrameInputs, SolverSettings, harmonic_constraint

FRAMES = 4


def bandwidth(edges: np.ndarray, rank: np.ndarray) -> int:
    return int(np.abs(rank[edges[:, 0]] - rank[edges[:, 1]]).max())


@pytest.fixture(scope="module")
def fine_pants():
    """Pants subdivided once (Loop lists the edge midpoints after the coarse vertices: a poor order to store), a
    karate motion's capsules and pin targets, and a harmonic constraint with its targets from the coarse rest
    shape moved with the pins' mean motion."""
    skel = default_skeleton()
    garment = make_garment("pants", skel, max_edge=0.1)
    S, faces = loop_subdivide(garment.vertices, garment.faces, levels=1)
    vertices = S @ garment.vertices
    ids = garment.attachment   # coarse vertices keep their ids
    state = body_state(skel, make_motion("karate", FRAMES + 1, settle_frames=0, blend_frames=2))
    a, b, ra, rb = capsules_world(skel, state.transforms)
    targets = linear_blend_skinning(garment.vertices[ids], garment.attachment_part[:, None], np.ones((len(ids), 1)),
                                    rest_transforms(skel), state.transforms)
    basis, _, mass = harmonic_basis(vertices, faces, harmonic_count(len(vertices)))
    constraint = harmonic_constraint(basis, mass, ids)
    shift = (targets - targets[:1]).mean(axis=1)                      # (F, 3)
    goals = np.stack([constraint.mass_basis.T @ (vertices + d) for d in shift])
    return vertices, faces, ids, np.stack([a, b], axis=2), np.stack([ra[0], rb[0]], axis=1), targets, constraint, goals


def test_locality_order_narrows_the_band_of_a_subdivided_mesh(fine_pants):
    vertices, faces = fine_pants[:2]
    edges = unique_edges(faces)
    order = locality_order(len(vertices), edges)
    assert np.array_equal(np.sort(order), np.arange(len(vertices)))           # a permutation
    rank = inverse_order(order)
    assert np.array_equal(order[rank], np.arange(len(vertices)))
    before, after = bandwidth(edges, np.arange(len(vertices))), bandwidth(edges, rank)
    assert after * 10 < before, (before, after)


def run(fine_pants, settings, reorder, harmonic):
    vertices, faces, ids, capsules, radii, targets, constraint, goals = fine_pants
    extra = dict(harmonic=constraint, harmonic_target=goals[0]) if harmonic else {}
    solver = ClothSolver(vertices, faces, settings, "cpu", ids, capsules=capsules[0], capsule_radii=radii,
                         reorder=reorder, **extra)
    positions = []
    for f in range(1, FRAMES + 1):
        solver.step(solver.state, FrameInputs(pin_targets=targets[f], capsules=capsules[f],
                                              harmonic_target=goals[f] if harmonic else None))
        positions.append(solver.state.read_world_positions()[0])
    return np.stack(positions), solver.state.read_velocities(), solver


def test_storage_order_leaves_the_motion_bit_for_bit(fine_pants):
    """Distance constraints, pins and the body: each vertex sums the same terms in the same order either way."""
    settings = SolverSettings(substeps=2, iterations=10, body_collision=True)
    stored, v_stored, solver = run(fine_pants, settings, reorder=True, harmonic=False)
    given, v_given, plain = run(fine_pants, settings, reorder=False, harmonic=False)
    assert not np.array_equal(solver.state.vertex_order, plain.state.vertex_order)   # it did reorder
    assert (solver.capsules.push.numpy() > 0).any()                                   # and the body acted
    np.testing.assert_array_equal(stored, given)
    np.testing.assert_array_equal(v_stored, v_given)
    assert np.abs(stored[-1] - stored[0]).max() > 0.01                                # the cloth moved


def test_storage_order_with_self_contact_and_harmonic_projection(fine_pants):
    """The projection's reduction runs over rows in storage order (and contact lists by triangle id): the same
    motion up to float rounding, which contacts amplify where they switch on or off. So the reference is what
    rounding does: the same run with its harmonic targets changed by 1e-7 relative (float32's epsilon)."""
    settings = SolverSettings(substeps=2, iterations=10, body_collision=True, self_collision=True,
                              harmonic_every="substep")
    stored, _, solver = run(fine_pants, settings, reorder=True, harmonic=True)
    given, _, _ = run(fine_pants, settings, reorder=False, harmonic=True)
    rounded = (*fine_pants[:-1], fine_pants[-1] * (1 + 1e-7))
    perturbed, _, _ = run(rounded, settings, reorder=False, harmonic=True)
    assert solver.contacts.vertex_count.numpy().max() > 0                             # self-contact acted
    reordering, rounding = np.abs(stored - given), np.abs(perturbed - given)
    assert 0 < reordering.mean() <= 2 * rounding.mean() + 1e-7, (reordering.mean(), rounding.mean())
    assert reordering.max() <= 2 * rounding.max() + 1e-6, (reordering.max(), rounding.max())


def test_state_reads_and_writes_in_the_callers_order(fine_pants):
    vertices, faces, ids = fine_pants[:3]
    solver = ClothSolver(vertices, faces, SolverSettings(substeps=1, iterations=2), "cpu", ids)
    velocities = np.random.default_rng(0).normal(scale=0.1, size=vertices.shape)
    velocities[ids] = 0.0
    solver.state.write_velocities(velocities)
    np.testing.assert_allclose(solver.state.read_velocities(), velocities, atol=1e-7)   # float32 round trip
    before = solver.state.read_world_positions()
    np.testing.assert_allclose(before[0], vertices, atol=1e-6)
    solver.step(solver.state, FrameInputs(pin_targets=vertices[ids]))
    after = solver.state.read_world_positions()
    np.testing.assert_allclose(before[0], vertices, atol=1e-6)    # a copy: stepping did not change it
    np.testing.assert_array_equal(after[0][ids], vertices[ids].astype(np.float32))   # the pins: caller's ids
    assert np.abs(after[0] - vertices).max() > 1e-3
