"""Fixed vertex (eq. 2) and geodesic distances, against analytic distances on a plane and a sphere."""
import numpy as np

from meshops.geodesic import (fixed_vertex, geodesic_distance, geodesic_sources, graph_geodesic_distance,
                              heat_geodesic_distance)
from meshops_shapes import cube_sphere, grid_patch, mesh_of
from geometry.mesh import unique_edges


def test_fixed_vertex_is_the_top_centre_of_the_bounding_box_with_y_up():
    vertices, _ = grid_patch(5, 5, 2.0, 1.0)
    assert np.allclose(vertices[fixed_vertex(vertices)], [1.0, 1.0, 0.0])
    lying = vertices[:, [0, 2, 1]]  # the same flag lying flat: top = the whole sheet, middle wins
    assert np.allclose(lying[fixed_vertex(lying)], [1.0, 0.0, 0.5])
    sphere = mesh_of("sphere")[0]
    assert np.allclose(sphere[fixed_vertex(sphere)], [0, 1, 0])


def test_heat_distance_on_a_flat_sheet_is_close_to_euclidean_and_beats_edge_paths():
    vertices, faces = grid_patch(61, 51, 1.2, 1.0)
    edges = unique_edges(faces)
    source = geodesic_sources(vertices, edges)
    exact = np.linalg.norm(vertices - vertices[source[0]], axis=1)
    heat, method = geodesic_distance(vertices, faces, edges, source)
    edge_paths = graph_geodesic_distance(vertices, edges, source)
    spacing = 0.02
    assert method == "heat"
    assert np.abs(heat - exact).mean() < 0.5 * spacing
    assert np.abs(heat - exact).max() < 2.5 * spacing
    assert np.abs(heat - exact).mean() < 0.25 * np.abs(edge_paths - exact).mean()


def test_heat_distance_on_a_sphere_follows_great_circles():
    vertices, faces = cube_sphere(16)
    edges = unique_edges(faces)
    source = geodesic_sources(vertices, edges)
    exact = np.arccos(np.clip(vertices @ vertices[source[0]], -1, 1))
    heat = heat_geodesic_distance(vertices, faces, edges, source)
    assert np.abs(heat - exact).max() < 0.03 * np.pi
    assert np.abs(heat - exact).mean() < 0.25 * np.abs(graph_geodesic_distance(vertices, edges, source) - exact).mean()


def test_an_underflowing_heat_step_falls_back_to_edge_paths():
    vertices, faces = grid_patch(1600, 2, 1600.0, 1.0)  # ~1600 edge lengths long
    edges = unique_edges(faces)
    source = geodesic_sources(vertices, edges)
    assert heat_geodesic_distance(vertices, faces, edges, source) is None
    distance, method = geodesic_distance(vertices, faces, edges, source)
    assert method == "dijkstra"
    assert np.allclose(distance, graph_geodesic_distance(vertices, edges, source))


def test_every_connected_piece_gets_its_own_source_closest_to_the_same_point():
    a_vertices, a_faces = grid_patch(6, 6)
    b_vertices = a_vertices + [3.0, -2.0, 0.0]
    vertices = np.concatenate([b_vertices, a_vertices])
    faces = np.concatenate([a_faces, a_faces + len(a_vertices)])
    edges = unique_edges(faces)
    sources = geodesic_sources(vertices, edges)
    assert len(sources) == 2
    assert sources[0] == fixed_vertex(vertices)
    assert np.allclose(vertices[sources[1]], [3.0, -1.0, 0.0])  # the far piece's corner nearest (2, 1, 0)
    distance, _ = geodesic_distance(vertices, faces, edges, sources)
    assert np.all(np.isfinite(distance)) and np.allclose(distance[sources], 0)
