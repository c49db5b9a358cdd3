"""One-ring order, k-ring distances and boundary walks, checked against trimesh and scipy."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import trimesh

from meshops.rings import boundary_walk, ordered_one_ring, pair_lookup, ring_distances, vertex_normals
from meshops_shapes import TEST_MESHES, grid_patch, mesh_of


@pytest.mark.parametrize("name", sorted(TEST_MESHES))
def test_one_ring_is_the_neighbour_set_in_counter_clockwise_face_order(name):
    vertices, faces = mesh_of(name)
    ring, size, is_open = ordered_one_ring(len(vertices), faces)
    reference = trimesh.Trimesh(vertices, faces, process=False)
    directed = {tuple(e) for f in faces for e in (f[[0, 1]], f[[1, 2]], f[[2, 0]])}
    for v, neighbours in enumerate(reference.vertex_neighbors):
        row = ring[v, :size[v]]
        assert sorted(row) == sorted(neighbours)
        assert np.all(ring[v, size[v]:] == -1)
        # Consecutive neighbours (n, p) around v form the counter-clockwise face (v, n, p).
        pairs = zip(row[:-1], row[1:]) if is_open[v] else zip(row, np.roll(row, -1))
        assert all((v, n) in directed and (n, p) in directed and (p, v) in directed for n, p in pairs)
    assert np.array_equal(is_open, np.isin(np.arange(len(vertices)), reference.outline().referenced_vertices))


def test_boundary_ring_runs_from_one_boundary_edge_to_the_other():
    vertices, faces = grid_patch(4, 4)
    ring, size, is_open = ordered_one_ring(len(vertices), faces)
    # Corner 0 of the grid: neighbours right (1), diagonal (5), up (4); counter-clockwise seen from +z.
    assert list(ring[0, :size[0]]) == [1, 5, 4] and is_open[0]
    # Interior vertex 5 starts at its smallest neighbour and turns counter-clockwise.
    assert list(ring[5, :size[5]]) == [0, 1, 6, 10, 9, 4] and not is_open[5]


@pytest.mark.parametrize("name", ["pants", "irregular", "torus"])
def test_ring_distances_match_breadth_first_search(name):
    vertices, faces = mesh_of(name)
    n = len(vertices)
    edges = trimesh.Trimesh(vertices, faces, process=False).edges_unique
    indptr, neighbour, distance = ring_distances(n, edges, 3)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    hops = csgraph.shortest_path(graph, directed=False, unweighted=True, indices=np.arange(0, n, 7))
    for row, v in enumerate(range(0, n, 7)):
        expected = np.flatnonzero(hops[row] <= 3)
        assert np.array_equal(neighbour[indptr[v]:indptr[v + 1]], expected)
        assert np.array_equal(distance[indptr[v]:indptr[v + 1]], hops[row, expected])
    find = pair_lookup(indptr, neighbour, n)
    assert np.all(find(np.array([0, 0]), np.array([0, -1])) == [indptr[0], -1])


@pytest.mark.parametrize("name", ["square", "pants", "irregular", "two_triangles", "sphere"])
def test_boundary_walk_follows_the_outline_with_the_mesh_on_the_left(name):
    vertices, faces = mesh_of(name)
    following, preceding = boundary_walk(len(vertices), faces)
    outline = trimesh.Trimesh(vertices, faces, process=False).outline()
    on_boundary = following >= 0
    assert np.array_equal(np.flatnonzero(on_boundary), np.unique(outline.referenced_vertices))
    assert np.array_equal(preceding[following[on_boundary]], np.flatnonzero(on_boundary))
    directed = {tuple(e) for f in faces for e in (f[[0, 1]], f[[1, 2]], f[[2, 0]])}
    assert all((v, following[v]) in directed for v in np.flatnonzero(on_boundary))


def test_vertex_normals_point_out_of_a_sphere_and_along_z_on_a_flag():
    vertices, faces = mesh_of("sphere")
    assert np.all(np.einsum("ij,ij->i", vertex_normals(vertices, faces), vertices) > 0.99)
    vertices, faces = mesh_of("square")
    assert np.allclose(vertex_normals(vertices, faces), [0, 0, 1])
