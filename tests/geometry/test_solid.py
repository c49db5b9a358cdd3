"""Points inside a closed mesh and their distance to it (geometry.solid), against shapes whose inside is known: a
sphere, a torus, and a box whose vertices lie on the lines the rays run along, where a naive count would meet an
edge or a vertex twice."""
import numpy as np
import pytest

from geometry.shapes import cube_sphere, torus
from geometry.solid import distance_to_mesh, inside_mesh
from geometry.tets import kuhn_grid


def box_surface():
    """The unit cube's surface as the outer faces of a 2 x 2 x 2 Kuhn grid, outward: every vertex on the lattice
    of spacing 0.5, the diagonals of its faces running both ways."""
    nodes, tets = kuhn_grid((2, 2, 2), np.zeros(3), 0.5)
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    keys, index, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    return nodes, faces[index[counts == 1]]


def test_rays_through_the_vertices_and_edges_of_a_box_count_each_crossing_once():
    vertices, faces = box_surface()
    ticks = np.array([-0.25, 0.25, 0.5, 0.75, 1.25])     # 0.5: through vertices and edges; 0.25: across diagonals
    heights = np.array([-0.1, 0.1, 0.3, 0.5 + 1e-3, 0.7, 0.9, 1.1])
    points = np.stack(np.meshgrid(ticks, ticks, heights, indexing="ij"), -1).reshape(-1, 3)
    expected = ((points > 0) & (points < 1)).all(axis=1)
    np.testing.assert_array_equal(inside_mesh(vertices, faces, points), expected)


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_random_points_inside_a_sphere_and_a_torus(shape):
    rng = np.random.default_rng(1)
    points = rng.uniform(-1.6, 1.6, (4000, 3))
    if shape == "sphere":
        vertices, faces = cube_sphere(12, 1.0)
        depth = 1.0 - np.linalg.norm(points, axis=1)
        # The mesh is a polyhedron inscribed in the sphere: points between the two are left out.
        far = (depth > 0.02) | (depth < 0)
    else:
        vertices, faces = torus(48, 24, 1.0, 0.35)
        ring = np.hypot(np.hypot(points[:, 0], points[:, 2]) - 1.0, points[:, 1])     # around y
        depth = 0.35 - ring
        far = np.abs(depth) > 0.02
        turn = np.linalg.qr(rng.standard_normal((3, 3)))[0]                           # and then any way up
        vertices, points = vertices @ turn.T, points @ turn.T
    got = inside_mesh(vertices, faces, points)
    np.testing.assert_array_equal(got[far], depth[far] > 0)
    # A point's answer does not depend on which other points are asked about with it.
    np.testing.assert_array_equal(inside_mesh(vertices, faces, points[:7]), got[:7])


def test_distances_to_the_surface():
    vertices, faces = box_surface()
    points = np.array([[0.5, 0.5, 0.5], [0.2, 0.5, 0.5], [2.0, 0.5, 0.5], [2.0, 2.0, 0.5], [0.5, 0.5, 1.0]])
    np.testing.assert_allclose(distance_to_mesh(vertices, faces, points), [0.5, 0.2, 1.0, np.sqrt(2), 0.0],
                               atol=1e-12)
