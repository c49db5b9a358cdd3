"""Convolution tables: the properties issue #3 lists, on every test mesh and level, plus hand-checked rows."""
import itertools

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import trimesh

from meshops.conv import assignment_table, conv_table, ellipse_samples, ring_samples, spiral_table
from meshops.neighbourhood import build_neighbourhood, midway_dummy
from meshops_shapes import TEST_MESHES, grid_patch, mesh_of, operators_of

L = 13


def _hops(vertices, faces, sources=None):
    edges = trimesh.Trimesh(vertices, faces, process=False).edges_unique
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return csgraph.shortest_path(graph.tocsr(), method="D", directed=False, unweighted=True, indices=sources)


def _levels(name):
    """Level 0 and every third level below it of a test mesh (levels 0, 3, 6, 9)."""
    return operators_of(name)[::3]


@pytest.mark.parametrize("name", sorted(TEST_MESHES))
@pytest.mark.parametrize("kind", ["RC13", "EC13"])
def test_assignment_rows_hold_the_vertex_its_one_ring_and_distinct_3_ring_vertices(name, kind):
    for level in _levels(name):
        vertices, faces, table = level.vertices, level.faces, level.conv[kind]
        n = len(vertices)
        hops = _hops(vertices, faces)
        boundary = np.unique(trimesh.Trimesh(vertices, faces, process=False).outline().referenced_vertices)
        to_boundary = hops[:, boundary].min(axis=1) if len(boundary) else np.full(n, np.inf)
        assert table.shape == (n, L) and table.dtype == np.int32
        assert np.array_equal(table[:, 0], np.arange(1, n + 1))
        for v in range(n):
            ids = table[v, 1:][table[v, 1:] > 0] - 1
            assert len(np.unique(ids)) == len(ids), "a vertex appears twice in a row"
            assert np.all((hops[v, ids] >= 1) & (hops[v, ids] <= 3))
            one_ring = np.flatnonzero(hops[v] == 1)
            if len(one_ring) <= L - 1:
                assert set(one_ring) <= set(ids)
            if to_boundary[v] >= 3 and np.sum((hops[v] >= 1) & (hops[v] <= 3)) >= L - 1:
                assert np.all(table[v] > 0), "an interior row with a large 3-ring is padded"
            if to_boundary[v] == 0 and len(one_ring) + 1 <= L - 1:
                assert np.any(table[v] == 0), "a boundary row has no padding slot"


def _hexagon():
    angle = np.radians(90 + 60 * np.arange(6))
    vertices = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(angle), np.sin(angle), np.zeros(6)]]
    faces = np.array([[0, 1 + i, 1 + (i + 1) % 6] for i in range(6)])
    return vertices, faces


def test_ring_samples_of_a_regular_hexagon_alternate_corners_and_midpoints_from_the_top():
    vertices, faces = _hexagon()
    nb = build_neighbourhood(vertices, faces)
    corners = vertices[1:]  # counter-clockwise from the top vertex, which is the fixed vertex
    expected = np.stack([corners, (corners + np.roll(corners, -1, axis=0)) / 2], axis=1).reshape(12, 3)
    assert np.allclose(ring_samples(nb, 12)[0], expected)
    table, _ = conv_table(nb, "RC", 13)
    assert list(table[0]) == [1, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7, 0]


def test_ellipse_samples_of_a_regular_hexagon_lie_evenly_on_its_circumcircle():
    vertices, faces = _hexagon()
    samples, fallback = ellipse_samples(build_neighbourhood(vertices, faces), 12)
    angle = np.radians(90 + 30 * np.arange(12))
    assert not fallback[0]
    assert np.allclose(samples[0], np.c_[np.cos(angle), np.sin(angle), np.zeros(12)], atol=1e-6)
    assert np.all(fallback[1:]), "three-point boundary rings cannot determine an ellipse"


def test_assignment_is_the_lexicographic_optimum_found_by_brute_force():
    vertices, faces = mesh_of("irregular")
    nb = build_neighbourhood(vertices, faces)
    hops = _hops(vertices, faces)
    samples = ring_samples(nb, 3)
    table = assignment_table(nb, samples)
    interior = [v for v in range(len(vertices)) if v not in set(nb.dummy_owner)]
    for v in interior[::40]:
        candidates = np.flatnonzero((hops[v] >= 1) & (hops[v] <= 3))
        distance = np.linalg.norm(samples[v][:, None] - vertices[candidates][None], axis=-1)
        corner = hops[v, candidates] == 1
        picks = np.array(list(itertools.permutations(range(len(candidates)), 3)))
        corners_used = corner[picks].sum(axis=1)
        total = distance[np.arange(3), picks].sum(axis=1)
        best = (-corners_used.max(), total[corners_used == corners_used.max()].min())
        chosen = np.searchsorted(candidates, table[v, 1:] - 1)
        ours = (-int(corner[chosen].sum()), distance[[0, 1, 2], chosen].sum())
        assert ours[0] == best[0] and ours[1] == pytest.approx(best[1], abs=1e-5 * nb.scale)


def test_spiral_rows_of_a_grid_vertex_match_the_hand_derived_spiral():
    # 5x5 grid, spacing 0.25, cells split along (i, j)-(i+1, j+1); vertex 12 = (2, 2) is the centre and the
    # fixed vertex is 22 = (2, 4), so the first neighbour is 17 = (2, 3), straight up.
    vertices, faces = grid_patch(5, 5)
    nb = build_neighbourhood(vertices, faces)
    spiral = [12, 17, 11, 6, 7, 13, 18,                    # one-ring, counter-clockwise from up
              22, 16, 10, 5, 0, 1, 2, 8, 14, 19, 24, 23,    # two-ring, counter-clockwise from up
              21, 15, 3, 9]                                 # three-ring (clipped by the grid)
    assert list(conv_table(nb, "SP", 13)[0][12]) == [v + 1 for v in spiral[:13]]
    assert list(conv_table(nb, "SPD", 13)[0][12]) == [v + 1 for v in spiral[::2]] + [0]


@pytest.mark.parametrize("name", sorted(TEST_MESHES))
def test_spirals_run_ring_by_ring_and_pad_only_at_the_end(name):
    for level in _levels(name):
        nb = build_neighbourhood(level.vertices, level.faces)
        hops = _hops(level.vertices, level.faces)
        sp_table, spd_table = level.conv["SP13"], level.conv["SPD13"]
        assert np.array_equal(spiral_table(nb, 25, 1)[:, ::2], spd_table), "SPD is SP with dilation 2"
        for row, v in zip(sp_table, range(len(sp_table))):
            used = row[row > 0] - 1
            assert row[0] == v + 1 and len(np.unique(used)) == len(used)
            assert np.all(row[len(used):] == 0), "padding only after the spiral runs out"
            assert np.all(np.diff(hops[v, used]) >= 0), "rings in order"
            if len(used) < L:
                assert len(used) == np.sum(hops[v] <= 3), "padding only when the 3-ring is exhausted"


def test_one_ring_dummy_of_a_corner_points_diagonally_out_at_the_mean_distance():
    vertices, faces = grid_patch(4, 4, 3.0, 1.5)  # spacings 1 and 0.5
    nb = build_neighbourhood(vertices, faces)
    corner = (nb.dummy_owner == 0) & (nb.dummy_ring == 1)
    assert np.allclose(nb.dummy_position[corner], [[-0.75 / np.sqrt(2), -0.75 / np.sqrt(2), 0]])
    straight = midway_dummy(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([[-1.0, 0, 0]]),
                            np.array([[2.0, 0, 0]]))
    assert np.allclose(straight, [[0, -1.5, 0]])


def test_ring_dummies_complete_the_cut_rings_and_lie_outside_the_sheet():
    vertices, faces = grid_patch(12, 10, 1.1, 0.9)
    nb = build_neighbourhood(vertices, faces)
    hops = _hops(vertices, faces)
    boundary = np.unique(trimesh.Trimesh(vertices, faces, process=False).outline().referenced_vertices)
    to_boundary = hops[:, boundary].min(axis=1)
    for k in (1, 2, 3):
        assert np.array_equal(np.unique(nb.dummy_owner[nb.dummy_ring == k]), np.flatnonzero(to_boundary <= k - 1))
    # Away from the corners a straight boundary cuts each ring once; near a corner a ring can be cut twice.
    i, j = np.arange(len(vertices)) % 12, np.arange(len(vertices)) // 12
    far_from_corners = (np.minimum(i, 11 - i) > 3) | (np.minimum(j, 9 - j) > 3)
    count = np.bincount(nb.dummy_owner, minlength=len(vertices))
    assert np.array_equal(count[far_from_corners], np.maximum(3 - to_boundary, 0)[far_from_corners])
    assert count.max() <= 6
    x, y = nb.dummy_position[:, 0], nb.dummy_position[:, 1]
    outside = (x < 0) | (x > 1.1) | (y < 0) | (y > 0.9)
    assert np.all(outside[far_from_corners[nb.dummy_owner]])
    # Midway between ends on two sides of a corner, a dummy can fall on the corner or just inside it, but
    # always on the far side of its vertex from the middle of the sheet.
    away = nb.dummy_position - vertices[nb.dummy_owner]
    assert np.all(np.einsum("ij,ij->i", away, vertices[nb.dummy_owner] - [0.55, 0.45, 0]) > 0)
