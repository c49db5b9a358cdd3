"""Welding seam vertices and cutting a mesh open along seams (geometry.mesh): the weld against a brute-force
reference, the cut against analytic counts, and the two as inverses."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import cut_along_edges, unique_edges, validate_mesh, weld_vertices
from geometry.shapes import cube_sphere, grid_patch, pants, torus


def brute_force_weld(vertices, faces, tolerance):
    """Union-find over every pair closer than the tolerance; each group is its lowest vertex, groups in order of
    their lowest vertex; faces with a repeated corner dropped."""
    n = len(vertices)
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i
    for i in range(n):
        for j in range(i + 1, n):
            if np.linalg.norm(vertices[i] - vertices[j]) <= tolerance:
                a, b = root(i), root(j)
                parent[max(a, b)] = min(a, b)
    roots = [root(i) for i in range(n)]
    kept = sorted(set(roots))
    old_to_new = np.array([kept.index(r) for r in roots])
    new_faces = [old_to_new[f] for f in faces if len(set(old_to_new[f])) == 3]
    return vertices[kept], np.array(new_faces).reshape(-1, 3), old_to_new


@pytest.mark.parametrize("seed", range(5))
def test_weld_matches_a_brute_force_reference(seed):
    rng = np.random.default_rng(seed)
    # clusters of near-duplicates (some chained: a-b and b-c close, a-c not), exact duplicates and loners
    centres = rng.uniform(-1, 1, size=(40, 3))
    tolerance = 0.01
    vertices = np.concatenate([centres,
                               centres[:15] + rng.normal(scale=0.003, size=(15, 3)),
                               centres[:5] + [0.008, 0, 0], centres[:5] + [0.016, 0, 0],   # chains
                               centres[20:30]])                                            # exact copies
    vertices = vertices[rng.permutation(len(vertices))]
    faces = rng.integers(0, len(vertices), size=(120, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    welded = weld_vertices(vertices, faces, tolerance)
    reference = brute_force_weld(vertices, faces, tolerance)
    for got, want in zip(welded, reference):
        assert np.array_equal(got, want)
    assert len(welded[0]) < len(vertices) and len(welded[1]) < len(faces)   # it merged and it dropped


def test_weld_of_tolerance_zero_merges_exact_duplicates_only_and_bad_tolerances_are_refused():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1e-12, 0], [0, 1, 0.0]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    welded, new_faces, old_to_new = weld_vertices(vertices, faces, 0.0)
    assert np.array_equal(old_to_new, [0, 1, 2, 1, 3, 2])
    assert np.array_equal(welded, vertices[[0, 1, 2, 4]]) and np.array_equal(new_faces, [[0, 1, 2], [1, 3, 2]])
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="weld tolerance must be finite and >= 0"):
            weld_vertices(vertices, faces, bad)


@pytest.mark.parametrize("shape", ["pants", "torus", "sphere"])
def test_a_cut_mesh_welds_back_to_itself_exactly(shape):
    vertices, faces = {"pants": lambda: pants(12), "torus": lambda: torus(24, 10), "sphere": lambda: cube_sphere(6)}[shape]()
    edges = unique_edges(faces)
    cut = edges[np.random.default_rng(1).random(len(edges)) < 0.3]
    cut_vertices, cut_faces, new_to_old = cut_along_edges(vertices, faces, cut)
    validate_mesh(cut_vertices, cut_faces)
    assert len(cut_vertices) > len(vertices) and np.array_equal(cut_vertices, vertices[new_to_old])
    assert np.array_equal(new_to_old[cut_faces], faces)                 # same faces, same corners
    shortest = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).min()
    welded, welded_faces, old_to_new = weld_vertices(cut_vertices, cut_faces, shortest / 2)
    assert np.array_equal(welded, vertices) and np.array_equal(welded_faces, faces)
    assert np.array_equal(old_to_new, new_to_old)


def test_cuts_duplicate_the_seam_vertices_of_each_fan():
    vertices, faces = grid_patch(5, 5)               # vertex i + 5 j at (i / 4, j / 4)
    column = 2 + 5 * np.arange(5)                    # the middle column, from one border to the other
    through = np.stack([column[:-1], column[1:]], axis=1)
    cut_vertices, cut_faces, new_to_old = cut_along_edges(vertices, faces, through)
    assert len(cut_vertices) == 25 + 5 and np.array_equal(np.flatnonzero(np.bincount(new_to_old) == 2), column)
    assert _pieces(cut_vertices, cut_faces) == 2
    # a slit from the border to the middle: its inner end keeps one fan, so one copy
    slit_vertices, slit_faces, slit_to_old = cut_along_edges(vertices, faces, through[:2][::-1])
    assert np.array_equal(np.flatnonzero(np.bincount(slit_to_old) == 2), column[:2])
    assert _pieces(slit_vertices, slit_faces) == 1
    # border edges and edges that are not in the mesh change nothing
    same = cut_along_edges(vertices, faces, [[0, 1], [0, 24]])
    assert np.array_equal(same[0], vertices) and np.array_equal(same[1], faces)


def _pieces(vertices, faces):
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    return csgraph.connected_components(graph, directed=False)[0]
