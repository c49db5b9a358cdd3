"""Operators of garments modelled as separate panels (issue 13 item 5): duplicated seam vertices, panels that meet
themselves along a seam, slivers and tiny pieces. Every piece keeps working at every pooling level: finite
positions, tables in range whose entries never leave the vertex's own piece, and no NaN on the way (a seam copy
of a vertex inside its own 3-ring once made a ring dummy NaN and the assignment fail)."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import unique_edges, validate_mesh
from meshops import build_operators
from meshops.neighbourhood import NO_DIRECTION, build_neighbourhood, midway_dummy, tangent_directions
from meshops.rings import ring_distances
from panelled_shapes import PANELLED_MESHES, panelled_mesh, sewn_tube

KINDS = ["RC9", "EC9", "SP9", "SPD9"]


def pieces(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Connected component of each vertex."""
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_vertices, n_vertices))
    return csgraph.connected_components(graph, directed=False)[1]


@pytest.mark.parametrize("name", list(PANELLED_MESHES))
def test_every_piece_keeps_finite_tables_on_its_own_piece_at_every_level(name):
    # the 10k-vertex mesh with the default tables (RC13, EC13, SP13, SPD13): about 6 s on one core
    levels = build_operators(*panelled_mesh(name), **({} if name == "large" else {"conv": KINDS}))
    assert len(levels) == 11
    n_pieces = pieces(len(levels[0].vertices), levels[0].faces).max() + 1
    if name == "large":
        assert len(levels[0].vertices) >= 10_000
    for index, level in enumerate(levels):
        n = len(level.vertices)
        assert np.isfinite(level.vertices).all()
        validate_mesh(level.vertices, level.faces)
        piece = pieces(n, level.faces)
        assert piece.max() + 1 == n_pieces, f"level {index}: a piece vanished or merged"
        for table_name, table in level.conv.items():
            assert table.dtype == np.int32 and table.min() >= 0 and table.max() <= n
            assert np.array_equal(table[:, 0], np.arange(1, n + 1))
            owner, column = np.nonzero(table)
            assert np.all(piece[table[owner, column] - 1] == piece[owner]), f"{table_name} reads across a seam"
            entries = np.sort(table, axis=1)
            assert not np.any((entries[:, 1:] == entries[:, :-1]) & (entries[:, 1:] > 0)), "an entry used twice"
        if level.coarsening is not None:
            coarse = pieces(len(level.coarsening.vertices), level.coarsening.faces)
            # pooling maps each piece onto one coarse piece, a different one for each
            pairs = np.unique(np.stack([piece, coarse[level.coarsening.unpool]], axis=1), axis=0)
            assert len(pairs) == n_pieces and len(np.unique(pairs[:, 1])) == n_pieces


def test_a_pooled_sewn_tube_brings_a_seam_copy_into_its_twins_three_ring_and_stays_finite():
    """The failure of issue 13 item 5, on the smallest mesh that shows it: a cuff of 4 quads around and 6 rings,
    closed by one seam. Two pooling passes leave it so narrow that the copy of a seam vertex lies within three
    rings of the vertex itself, at its very position, and ends a ring the boundary cuts."""
    levels = build_operators(*sewn_tube(4, 6), ["RC9", "EC9"], 4)
    seam_copy_in_three_ring = []
    for level in levels:
        n = len(level.vertices)
        indptr, neighbour, distance = ring_distances(n, unique_edges(level.faces), 3)
        owner = np.repeat(np.arange(n), np.diff(indptr))
        same_place = np.all(level.vertices[owner] == level.vertices[neighbour], axis=1) & (distance > 0)
        seam_copy_in_three_ring.append(bool(same_place.any()))
        nb = build_neighbourhood(level.vertices, level.faces)
        assert np.isfinite(nb.dummy_position).all() and np.isfinite(nb.tangent).all()
        for table in level.conv.values():
            assert table.min() >= 0 and table.max() <= n
    assert any(seam_copy_in_three_ring), "the case this test exists for did not occur"


def test_a_ring_end_at_the_vertex_itself_puts_the_dummy_opposite_the_other_end():
    centre = np.array([[1.0, 2.0, 3.0]] * 4)
    normal = np.array([[0.0, 0.0, 1.0]] * 4)
    end_b = centre + [[2.0, 0.0, 0.0], [2.0, 0.0, 5.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
    end_a = centre + [[0.0, 0.0, 0.0], [0.0, 0.0, 4.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    dummy = midway_dummy(centre, normal, end_a, end_b)
    # A on the centre: the whole turn is missing, so the dummy faces away from B at half B's distance
    np.testing.assert_allclose(dummy[0], centre[0] + [-1.0, 0.0, 0.0], atol=1e-12)
    # A on the normal line: no direction either; the distance is still the mean of the two
    np.testing.assert_allclose(dummy[1], centre[1] + [-(4 + np.sqrt(29)) / 2, 0.0, 0.0], atol=1e-12)
    # neither end has a direction: a finite point in the tangent plane at the mean distance
    assert np.isfinite(dummy).all()
    np.testing.assert_allclose(dummy[2:, 2], centre[2:, 2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(dummy[2:] - centre[2:], axis=1), [0.5, 0.0], atol=1e-12)


def test_tangent_directions_project_and_fall_back_to_a_fixed_unit_vector_of_the_plane():
    rng = np.random.default_rng(0)
    normal = rng.normal(size=(50, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = rng.normal(size=(50, 3))
    offset[:10] = normal[:10] * rng.uniform(0.5, 2.0, size=(10, 1))          # along the normal
    offset[10:15] = 0.0                                                       # a seam copy: no offset at all
    offset[15:20] = normal[15:20] + 0.1 * NO_DIRECTION * np.cross(normal[15:20], [1.0, 0.0, 0.0])  # nearly along
    length = np.linalg.norm(offset, axis=1)
    unit, defined = tangent_directions(offset, normal, length)
    assert np.array_equal(defined, np.arange(50) >= 20)
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nd,nd->n", unit, normal), 0.0, atol=1e-12)
    flat = offset[20:] - np.einsum("nd,nd->n", offset[20:], normal[20:])[:, None] * normal[20:]
    np.testing.assert_allclose(unit[20:], flat / np.linalg.norm(flat, axis=1, keepdims=True), atol=1e-12)
    # the fallback is the plane's direction nearest the coordinate axis least aligned with the normal
    axis = np.eye(3)[np.argmin(np.abs(normal[:20]), axis=1)]
    assert np.all(np.einsum("nd,nd->n", unit[:20], axis) > 0)
