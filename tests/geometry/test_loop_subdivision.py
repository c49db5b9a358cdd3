"""Loop subdivision matrix: against trimesh where trimesh is right, against hand-computed crease weights where
it is not, and against the invariants (affine rows, boundary independence, topology, orientation)."""
import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
import trimesh.remesh

from geometry.loop_subdivision import loop_beta, loop_subdivide, loop_subdivision_matrix
from geometry.mesh import boundary_vertex_mask, edge_faces, unique_edges, validate_mesh


def grid_patch(n, seed=0, corner_diagonals=True):
    """(n+1)² vertex grid with bumpy heights. With corner_diagonals, each cell's diagonal points toward the
    nearest patch corner, so no interior edge joins two boundary vertices and no triangle has two boundary
    edges (the case trimesh 5.2.0 gets right); otherwise every diagonal runs (i, j)-(i+1, j+1)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    height = np.random.default_rng(seed).uniform(-0.3, 0.3, i.shape)
    vertices = np.stack([i.ravel(), j.ravel(), height.ravel()], axis=1).astype(np.float64)
    ci, cj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b, c, d = ci * (n + 1) + cj, (ci + 1) * (n + 1) + cj, (ci + 1) * (n + 1) + cj + 1, ci * (n + 1) + cj + 1
    main_diagonal = ((2 * ci + 1 < n) == (2 * cj + 1 < n)) if corner_diagonals else np.ones_like(ci, dtype=bool)
    # Cell corners a=(i,j), b=(i+1,j), c=(i+1,j+1), d=(i,j+1); counter-clockwise seen from +z.
    tri_main = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], axis=-2)
    tri_anti = np.stack([np.stack([a, b, d], -1), np.stack([b, c, d], -1)], axis=-2)
    faces = np.where(main_diagonal[..., None, None], tri_main, tri_anti).reshape(-1, 3)
    return vertices, faces


def hemisphere():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    upper = sphere.submesh([np.nonzero(sphere.triangles_center[:, 1] > 0.0)[0]], append=True)
    return np.asarray(upper.vertices), np.asarray(upper.faces)


def random_closed():
    points = np.random.default_rng(3).normal(size=(80, 3))
    points *= np.random.default_rng(4).uniform(0.8, 1.2, (80, 1)) / np.linalg.norm(points, axis=1, keepdims=True)
    hull = trimesh.convex.convex_hull(points)
    return np.asarray(hull.vertices), np.asarray(hull.faces)


def icosphere():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def torus():
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=16, minor_sections=8)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def interior_edges_joining_boundary(n_vertices, faces):
    edges, sides = edge_faces(faces)
    on_boundary = boundary_vertex_mask(n_vertices, faces)
    return int(on_boundary[edges[sides[:, 1] >= 0]].all(axis=1).sum())


def assert_matches_trimesh(vertices, faces, levels=2):
    matrix, new_faces = loop_subdivide(vertices, faces, levels)
    ref_vertices, ref_faces = trimesh.remesh.subdivide_loop(vertices, faces, iterations=levels)
    assert new_faces.shape == ref_faces.shape and matrix.shape[0] == len(ref_vertices)
    # Faces correspond one to one (same split pattern); the odd vertices may be numbered differently, so map
    # our indices to trimesh's through the faces and check the map is a consistent bijection.
    to_ref = np.full(matrix.shape[0], -1)
    to_ref[new_faces.ravel()] = ref_faces.ravel()
    np.testing.assert_array_equal(to_ref[new_faces], ref_faces)
    assert len(np.unique(to_ref)) == matrix.shape[0]
    np.testing.assert_array_equal(to_ref[:len(vertices)], np.arange(len(vertices)))
    np.testing.assert_allclose(matrix @ vertices, ref_vertices[to_ref], atol=1e-6, rtol=0)


@pytest.mark.parametrize("make", [icosphere, torus, random_closed])
def test_matches_trimesh_on_closed_meshes(make):
    assert_matches_trimesh(*make())


@pytest.mark.parametrize("make", [lambda: grid_patch(5), hemisphere], ids=["grid", "hemisphere"])
def test_matches_trimesh_on_open_meshes_without_boundary_shortcuts(make):
    vertices, faces = make()
    # trimesh's boundary rule is only right when no interior edge joins two boundary vertices, at both levels.
    assert interior_edges_joining_boundary(len(vertices), faces) == 0
    matrix, once = loop_subdivision_matrix(vertices, faces)
    assert interior_edges_joining_boundary(matrix.shape[0], once) == 0
    assert_matches_trimesh(vertices, faces)


def test_loop_beta_known_values():
    # Valence 3: 3/16; 4: 31/256 (Warren's 3/(8n) would give 24/256); regular 6: 1/16; nβ → 5/8 - (5/8)² = 15/64.
    np.testing.assert_allclose(loop_beta(np.array([3, 4, 6])), [3 / 16, 31 / 256, 1 / 16])
    assert abs(1e6 * loop_beta(np.array([1e6]))[0] - 15 / 64) < 1e-9


def test_odd_vertices_follow_unique_edge_order():
    vertices, faces = grid_patch(3)
    matrix, _ = loop_subdivision_matrix(vertices, faces)
    edges, sides = edge_faces(faces)
    np.testing.assert_array_equal(edges, unique_edges(faces))
    odd = matrix[len(vertices):].toarray()
    ends = odd[np.arange(len(edges))[:, None], edges]
    expected = np.where(sides[:, 1:] < 0, 0.5, 3 / 8)
    np.testing.assert_allclose(ends, np.broadcast_to(expected, ends.shape))


def test_crease_rule_on_a_square_of_two_triangles():
    # Every vertex is on the boundary and the diagonal (0, 2) is an interior edge joining two of them: the
    # corners must take only their two boundary-edge neighbours.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    matrix, _ = loop_subdivision_matrix(vertices, faces)
    e = 1 / 8
    expected_even = np.array([[6 * e, e, 0, e], [e, 6 * e, e, 0], [0, e, 6 * e, e], [e, 0, e, 6 * e]])
    np.testing.assert_allclose(matrix[:4].toarray(), expected_even)
    # Edges in unique order: (0,1) (0,2) (0,3) (1,2) (2,3); only (0,2) is interior, with 1 and 3 opposite.
    expected_odd = np.array([[0.5, 0.5, 0, 0], [3 / 8, 1 / 8, 3 / 8, 1 / 8], [0.5, 0, 0, 0.5],
                             [0, 0.5, 0.5, 0], [0, 0, 0.5, 0.5]])
    np.testing.assert_allclose(matrix[4:].toarray(), expected_odd)


def test_crease_rule_on_2x2_patch():
    # 3x3 vertices, index 3 i + j; diagonals (i,j)-(i+1,j+1), so e.g. boundary vertex 3 = (1,0) is joined by
    # the interior edge (3, 7) to boundary vertex 7 = (2,1), which the crease rule must ignore.
    vertices, faces = grid_patch(2, corner_diagonals=False)
    matrix, _ = loop_subdivision_matrix(vertices, faces)
    dense = matrix.toarray()
    e = 1 / 8

    def row(weights):
        r = np.zeros(9)
        for k, w in weights.items():
            r[k] = w
        return r

    np.testing.assert_allclose(dense[3], row({3: 6 * e, 0: e, 6: e}))   # edge-middle boundary vertex
    np.testing.assert_allclose(dense[0], row({0: 6 * e, 3: e, 1: e}))   # corner with interior diagonal to 4
    np.testing.assert_allclose(dense[6], row({6: 6 * e, 3: e, 7: e}))   # corner of valence 2
    np.testing.assert_allclose(dense[4], row({4: 10 / 16, 0: 1 / 16, 1: 1 / 16, 3: 1 / 16, 5: 1 / 16,
                                              7: 1 / 16, 8: 1 / 16}))  # regular interior vertex, β = 1/16
    edges = unique_edges(faces)
    odd_37 = 9 + int(np.nonzero((edges == [3, 7]).all(axis=1))[0][0])
    np.testing.assert_allclose(dense[odd_37], row({3: 3 / 8, 7: 3 / 8, 6: 1 / 8, 4: 1 / 8}))


@pytest.mark.parametrize("make", [lambda: grid_patch(2, corner_diagonals=False), hemisphere, torus],
                         ids=["2x2-patch", "hemisphere", "torus"])
def test_rows_are_affine(make):
    vertices, faces = make()
    matrix, _ = loop_subdivide(vertices, faces, levels=2)
    np.testing.assert_allclose(np.asarray(matrix.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    rng = np.random.default_rng(1)
    linear, shift = rng.normal(size=(3, 3)), rng.normal(size=3)
    np.testing.assert_allclose(matrix @ (vertices @ linear.T + shift), (matrix @ vertices) @ linear.T + shift,
                               atol=1e-10)


def test_boundary_is_independent_of_interior():
    vertices, faces = grid_patch(4, corner_diagonals=False)
    matrix, new_faces = loop_subdivide(vertices, faces, levels=2)
    fine_boundary = boundary_vertex_mask(matrix.shape[0], new_faces)
    coarse_interior = ~boundary_vertex_mask(len(vertices), faces)
    moved = vertices.copy()
    moved[coarse_interior] += np.random.default_rng(2).normal(size=(coarse_interior.sum(), 3))
    np.testing.assert_array_equal((matrix @ moved)[fine_boundary], (matrix @ vertices)[fine_boundary])
    assert not np.allclose((matrix @ moved)[~fine_boundary], (matrix @ vertices)[~fine_boundary])


def test_boundary_follows_cubic_bspline_curve_subdivision():
    # Independent reference: the 1-D rule on the ordered boundary polygon (3/4, 1/8, 1/8 and midpoints).
    n = 3
    vertices, faces = grid_patch(n, corner_diagonals=False)
    side = np.arange(n)
    loop = np.concatenate([side * (n + 1), n * (n + 1) + side, (n - side) * (n + 1) + n, n - side])
    polygon = vertices[loop]
    prev_p, next_p = np.roll(polygon, 1, axis=0), np.roll(polygon, -1, axis=0)
    matrix, _ = loop_subdivision_matrix(vertices, faces)
    fine = matrix @ vertices
    np.testing.assert_allclose(fine[loop], 0.75 * polygon + (prev_p + next_p) / 8)
    edges = unique_edges(faces)
    keys = {tuple(e): len(vertices) + k for k, e in enumerate(edges)}
    odd = [keys[tuple(sorted((a, b)))] for a, b in zip(loop, np.roll(loop, -1))]
    np.testing.assert_allclose(fine[odd], (polygon + next_p) / 2)


@pytest.mark.parametrize("make", [icosphere, random_closed, lambda: grid_patch(4, corner_diagonals=False)],
                         ids=["icosphere", "random-closed", "grid"])
def test_counts_orientation_and_validity(make):
    vertices, faces = make()
    n_vertices, n_faces = len(vertices), len(faces)
    matrix, new_faces = loop_subdivide(vertices, faces, levels=2)
    once, once_faces = loop_subdivision_matrix(vertices, faces)
    assert once.shape == (n_vertices + len(unique_edges(faces)), n_vertices)
    assert matrix.shape == (once.shape[0] + len(unique_edges(once_faces)), n_vertices)
    assert new_faces.shape == (16 * n_faces, 3) and new_faces.dtype == np.int64
    assert matrix.format == "csr"
    fine = matrix @ vertices
    validate_mesh(fine, new_faces)

    def normals(v, f):
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    parent = np.repeat(np.arange(n_faces), 16)
    agreement = np.einsum("ij,ij->i", normals(fine, new_faces), normals(vertices, faces)[parent])
    assert (agreement > 0).all()


def test_zero_levels_is_identity():
    vertices, faces = icosphere()
    matrix, new_faces = loop_subdivide(vertices, faces, levels=0)
    assert (matrix != sp.identity(len(vertices))).nnz == 0
    np.testing.assert_array_equal(new_faces, faces)


def test_rejects_bad_input():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=np.float64)
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(ValueError, match="non-manifold"):
        loop_subdivision_matrix(vertices, fan)
    with pytest.raises(ValueError, match="levels"):
        loop_subdivide(*icosphere(), levels=-1)
