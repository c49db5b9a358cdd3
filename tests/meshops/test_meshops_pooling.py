"""Edge-collapse pooling: partition, independence, manifoldness, boundary loops, ratio and quadric errors."""
import numpy as np
import pytest
import trimesh

from meshops.pooling import collapse_pass, quadric_errors
from meshops_shapes import TEST_MESHES, grid_patch, mesh_of, operators_of
from geometry.mesh import edge_faces, validate_mesh


def _loops_and_euler(vertices, faces):
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    return len(mesh.outline().entities), mesh.euler_number


@pytest.mark.parametrize("name", sorted(TEST_MESHES))
def test_every_pass_is_a_set_of_independent_collapses_of_fine_edges(name):
    levels = operators_of(name)
    for fine, coarse in zip(levels[:-1], levels[1:]):
        pool, unpool = fine.coarsening.pool, fine.coarsening.unpool
        n_fine, n_coarse = len(fine.vertices), len(coarse.vertices)
        assert pool.shape == (n_coarse, 2) and unpool.shape == (n_fine,)
        members = np.concatenate([pool[:, 0], pool[pool[:, 1] != pool[:, 0], 1]])
        assert np.array_equal(np.sort(members), np.arange(n_fine)), "each fine vertex in exactly one coarse one"
        assert np.all(unpool[pool[:, 0]] == np.arange(n_coarse)) and np.all(unpool[pool[:, 1]] == np.arange(n_coarse))
        pairs = np.sort(pool[pool[:, 0] != pool[:, 1]], axis=1)
        edges = {tuple(e) for e in trimesh.Trimesh(fine.vertices, fine.faces, process=False).edges_unique}
        assert all(tuple(p) in edges for p in pairs), "a merged pair is not an edge"
        assert len(np.unique(pairs)) == 2 * len(pairs), "two collapsed edges share a vertex"
        assert len(pairs) == fine.coarsening.collapsed
        assert np.allclose(coarse.vertices, (fine.vertices[pool[:, 0]] + fine.vertices[pool[:, 1]]) / 2)


@pytest.mark.parametrize("name", sorted(TEST_MESHES))
def test_coarse_meshes_are_manifold_unfolded_and_keep_their_topology(name):
    levels = operators_of(name)
    loops, euler = _loops_and_euler(levels[0].vertices, levels[0].faces)
    for fine, coarse in zip(levels[:-1], levels[1:]):
        validate_mesh(coarse.vertices, coarse.faces)
        mapped = fine.coarsening.unpool[fine.faces]
        distinct = (mapped[:, 0] != mapped[:, 1]) & (mapped[:, 1] != mapped[:, 2]) & (mapped[:, 2] != mapped[:, 0])
        survivors = mapped[distinct]
        assert {tuple(f) for f in survivors} == {tuple(f) for f in coarse.faces}, "faces are the renumbered survivors"
        before, after = fine.vertices[fine.faces[distinct]], coarse.vertices[survivors]
        normal_before = np.cross(before[:, 1] - before[:, 0], before[:, 2] - before[:, 0])
        normal_after = np.cross(after[:, 1] - after[:, 0], after[:, 2] - after[:, 0])
        cosine = np.einsum("ij,ij->i", normal_before, normal_after) / (
            np.linalg.norm(normal_before, axis=1) * np.linalg.norm(normal_after, axis=1))
        assert cosine.min() > 0.09, "a face flipped (or nearly) between levels"
        p = coarse.vertices[coarse.faces]
        edge = np.roll(p, -1, axis=1) - p
        quality = 2 * np.sqrt(3) * np.linalg.norm(np.cross(edge[:, 0], -edge[:, 2]), axis=1) / np.sum(edge ** 2, (1, 2))
        assert quality.min() > 0.01, "a degenerate coarse face"
        assert _loops_and_euler(coarse.vertices, coarse.faces) == (loops, euler)


@pytest.mark.parametrize("name", [n for n in sorted(TEST_MESHES) if n != "two_triangles"])
def test_each_pass_keeps_half_to_three_fifths_of_the_vertices(name):
    for fine, coarse in zip(operators_of(name)[:-1], operators_of(name)[1:]):
        if len(fine.vertices) >= 300:
            assert 0.5 <= len(coarse.vertices) / len(fine.vertices) <= 0.6


def test_tiny_meshes_end_in_identity_levels():
    levels = operators_of("two_triangles")
    assert [len(level.vertices) for level in levels] == [4] + [3] * 10
    for level in levels[1:-1]:
        assert np.array_equal(level.coarsening.pool, np.stack([np.arange(3)] * 2, axis=1))
        assert np.array_equal(level.coarsening.unpool, np.arange(3)) and level.coarsening.collapsed == 0


def test_collapses_are_checked_against_the_mesh_the_earlier_collapses_left():
    # A valence-4 vertex whose two short opposite ring edges are the cheapest: collapsing both (each fine alone)
    # would leave it with two faces on the same three vertices.
    angle = np.radians([10, 170, 190, 350])
    vertices = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(angle), np.sin(angle), np.zeros(4)]]
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]])
    result = collapse_pass(vertices, faces, quadric_threshold=np.inf)
    merged = {tuple(sorted(p)) for p in result.pool if p[0] != p[1]}
    assert len(merged & {(1, 4), (2, 3)}) == 1, "exactly one of the two cheapest, conflicting edges collapses"
    validate_mesh(result.vertices, result.faces)


def test_threshold_stops_a_pass_just_below_three_fifths_only_on_curved_meshes():
    vertices, faces = mesh_of("sphere")
    n = len(vertices)
    strict = collapse_pass(vertices, faces, quadric_threshold=0.0)
    assert 0.6 * n - 1 <= len(strict.vertices) < 0.6 * n
    exhaustive = collapse_pass(vertices, faces, quadric_threshold=np.inf)
    assert len(exhaustive.vertices) < len(strict.vertices) - 0.05 * n
    flat_vertices, flat_faces = grid_patch(30, 20)
    assert len(collapse_pass(flat_vertices, flat_faces, 0.0).vertices) < 0.55 * len(flat_vertices)


def _reference_quadric_error(vertices, faces, edges, sides, e):
    """Sum of squared distances from the edge midpoint to every plane of either end, one term per owner end."""
    a, b = edges[e]
    midpoint = (vertices[a] + vertices[b]) / 2
    total = 0.0
    for f in np.flatnonzero(np.isin(faces, [a, b]).any(axis=1)):
        p = vertices[faces[f]]
        normal = np.cross(p[1] - p[0], p[2] - p[0])
        total += ((a in faces[f]) + (b in faces[f])) * np.dot(midpoint - p[0], normal / np.linalg.norm(normal)) ** 2
    for (u, w), f in zip(edges[sides[:, 1] < 0], sides[sides[:, 1] < 0, 0]):
        if {a, b} & {u, w}:
            p = vertices[faces[f]]
            fence = np.cross(vertices[w] - vertices[u], np.cross(p[1] - p[0], p[2] - p[0]))
            fence /= np.linalg.norm(fence)
            total += ((a in (u, w)) + (b in (u, w))) * np.dot(midpoint - vertices[u], fence) ** 2
    return total


@pytest.mark.parametrize("name", ["pants", "square", "irregular"])
def test_quadric_errors_sum_squared_distances_to_the_planes_of_both_ends(name):
    vertices, faces = mesh_of(name)
    edges, sides = edge_faces(faces)
    errors = quadric_errors(vertices, faces, edges, sides)
    for e in range(0, len(edges), max(1, len(edges) // 15)):
        assert errors[e] == pytest.approx(_reference_quadric_error(vertices, faces, edges, sides, e), abs=1e-12)
    if name == "square":  # flat: only the boundary fences can be missed, by edges leaving the boundary
        on_boundary = np.isin(edges, edges[sides[:, 1] < 0])
        leaving = on_boundary.any(axis=1) & (sides[:, 1] >= 0)
        assert np.allclose(errors[~on_boundary.any(axis=1)], 0, atol=1e-20)
        assert np.all(errors[leaving] > 1e-6)
