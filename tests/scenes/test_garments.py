"""Procedural garments: manifold, boundary loops and genus (checked with trimesh and by Euler characteristic),
orientation, edge lengths, triangle shape, clearance from the rest-pose body, attachments, and determinism."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import trimesh

import yaml

from geometry.mesh import edge_faces, unique_edges, validate_mesh, weld_vertices
from pipeline.core.config import resolve_scene
from scenes.capsules import body_signed_distance, capsule_signed_distance, capsules_world
from scenes.garments import BOUNDARY_LOOPS, CLEARANCE, GARMENT_KINDS, make_garment
from scenes.kinematics import rest_transforms
from scenes.registry import build_rest
from scenes.skeleton import default_skeleton

SKEL = default_skeleton()
REST = rest_transforms(SKEL)
CONFIG = yaml.safe_load(open("workflow_config.yaml"))


@pytest.fixture(scope="module")
def garments():
    return {(kind, max_edge): make_garment(kind, SKEL, max_edge=max_edge)
            for kind in GARMENT_KINDS for max_edge in (0.08, 0.15)}


def boundary_loops(vertices, faces):
    """Vertex sets of the boundary loops: connected components of the graph of boundary edges."""
    edges, sides = edge_faces(faces)
    border = edges[sides[:, 1] < 0]
    graph = sp.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(len(vertices),) * 2)
    _, label = csgraph.connected_components(graph, directed=False)
    on_border = np.unique(border)
    return [on_border[label[on_border] == k] for k in np.unique(label[on_border])]


def min_angles(vertices, faces):
    tri = vertices[faces]
    angles = []
    for i in range(3):
        u, v = tri[:, (i + 1) % 3] - tri[:, i], tri[:, (i + 2) % 3] - tri[:, i]
        cos = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(angles, axis=0)


@pytest.mark.parametrize("max_edge", [0.08, 0.15])
@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_garment_is_a_manifold_with_the_expected_boundary(garments, kind, max_edge):
    g = garments[kind, max_edge]
    assert g.vertices.dtype == np.float64 and g.faces.dtype == np.int64
    validate_mesh(g.vertices, g.faces)
    mesh = trimesh.Trimesh(g.vertices, g.faces, process=False)
    assert mesh.is_winding_consistent and len(mesh.split(only_watertight=False)) == 1
    loops = boundary_loops(g.vertices, g.faces)
    assert len(loops) == BOUNDARY_LOOPS[kind] == len(mesh.outline().entities)
    # One connected orientable surface with b boundary loops and genus 0 has V - E + F = 2 - b.
    euler = len(g.vertices) - len(unique_edges(g.faces)) + len(g.faces)
    assert euler == 2 - BOUNDARY_LOOPS[kind]


@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_normals_point_away_from_the_body(garments, kind):
    g = garments[kind, 0.08]
    tri = g.vertices[g.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normal, axis=1)
    centroid, h = tri.mean(axis=1), 1e-5
    away = np.stack([body_signed_distance(SKEL, REST, centroid + h * e) - body_signed_distance(SKEL, REST,
                                                                                             centroid - h * e)
                     for e in np.eye(3)], axis=1)
    outward = (normal * away).sum(axis=1) > 0
    # Faces under the arms or beside the neck may face a limb that lies outside them; nearly all face away.
    assert area[outward].sum() > 0.95 * area.sum()


@pytest.mark.parametrize("max_edge", [0.04, 0.08, 0.15, 0.3])
@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_edges_are_shorter_than_max_edge_and_triangles_well_shaped(kind, max_edge):
    g = make_garment(kind, SKEL, max_edge=max_edge)
    edges = unique_edges(g.faces)
    length = np.linalg.norm(g.vertices[edges[:, 0]] - g.vertices[edges[:, 1]], axis=1)
    assert length.max() < max_edge
    assert length.min() > 0.1 * max_edge
    assert min_angles(g.vertices, g.faces).min() > (20.0 if kind == "pants" else 15.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_rest_garment_does_not_touch_the_body(kind, seed):
    for height in (1.7, 1.3):
        skel = default_skeleton(height)
        g = make_garment(kind, skel, max_edge=0.08 * height / 1.7, seed=seed)
        a, b, ra, rb = capsules_world(skel, rest_transforms(skel))
        gap = capsule_signed_distance(g.vertices, a, b, ra, rb)                # (V, every capsule)
        assert gap.min() >= CLEARANCE * height / 1.7


@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_attachment_vertices_exist_and_lie_near_their_parts(garments, kind):
    g = garments[kind, 0.08]
    assert len(g.attachment) >= 2 and len(np.unique(g.attachment)) == len(g.attachment)
    assert g.attachment.min() >= 0 and g.attachment.max() < len(g.vertices)
    assert g.attachment_part.shape == g.attachment.shape
    a, b, ra, rb = capsules_world(SKEL, REST)
    p = g.attachment_part
    gap = capsule_signed_distance(g.vertices[g.attachment], a, b, ra, rb)[np.arange(len(p)), p]
    assert (gap > 0).all() and (gap < 0.12).all()     # within a hand's width: shoulder seams ride on the chest
    expected = "pelvis" if kind in ("pants", "skirt") else "chest"
    assert {SKEL.names[i] for i in p} == {expected}


def test_garment_openings_are_where_they_belong(garments):
    pants = garments["pants", 0.08]
    waist, *legs = sorted(boundary_loops(pants.vertices, pants.faces), key=lambda l: -pants.vertices[l, 1].mean())
    assert set(waist) == set(pants.attachment)                         # the waist band is the top opening
    for leg in legs:
        assert pants.vertices[leg, 1].max() < 0.3                       # leg openings near the ankles
    assert sorted(np.sign(pants.vertices[leg, 0].mean()) for leg in legs) == [-1.0, 1.0]
    shirt = garments["tshirt", 0.08]
    loops = boundary_loops(shirt.vertices, shirt.faces)
    centers = np.array([shirt.vertices[l].mean(axis=0) for l in loops])
    neck, hem = np.argmax(centers[:, 1]), np.argmin(centers[:, 1])
    assert abs(centers[neck, 0]) < 0.01 and abs(centers[hem, 0]) < 0.01
    sleeves = np.setdiff1d(np.arange(4), [neck, hem])
    assert sorted(np.sign(centers[sleeves, 0])) == [-1.0, 1.0] and (np.abs(centers[sleeves, 0]) > 0.25).all()


def test_mesh_sizes_are_stable(garments):
    counts = {kind: len(garments[kind, 0.08].vertices) for kind in GARMENT_KINDS}
    assert 300 <= counts["pants"] <= 1500
    assert 200 <= counts["tshirt"] <= 1500 and 300 <= counts["dress"] <= 2000
    assert 150 <= counts["skirt"] <= 1000 and 150 <= counts["cape"] <= 1000 and 40 <= counts["patch"] <= 300
    assert all(len(garments[kind, 0.15].vertices) < 0.5 * counts[kind] for kind in GARMENT_KINDS)


@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_seeded_garments_are_deterministic_and_seeds_vary_the_design(kind):
    a, b, c = (make_garment(kind, SKEL, seed=s) for s in (4, 4, 5))
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    assert a.vertices.shape != c.vertices.shape or np.abs(a.vertices - c.vertices).max() > 1e-3


def test_invalid_requests_are_named():
    with pytest.raises(ValueError, match="unknown garment kind 'poncho'"):
        make_garment("poncho", SKEL)
    with pytest.raises(ValueError, match="max_edge must be positive"):
        make_garment("pants", SKEL, max_edge=0.0)


def pieces(vertices, faces):
    """Connected component of each vertex."""
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    return csgraph.connected_components(graph, directed=False)[1]


@pytest.mark.parametrize("max_edge", [0.08, 0.15])
@pytest.mark.parametrize("kind", GARMENT_KINDS)
def test_panels_are_separate_pieces_that_a_weld_sews_back_into_the_whole_garment(garments, kind, max_edge):
    whole = garments[kind, max_edge]
    panels = make_garment(kind, SKEL, max_edge=max_edge, panels=True)
    validate_mesh(panels.vertices, panels.faces)
    assert pieces(panels.vertices, panels.faces).max() + 1 >= 6     # 6-15 panels, whatever the garment
    # every vertex is a copy of a vertex of the whole garment, at exactly its position; seams have several
    _, _, original = weld_vertices(panels.vertices, panels.faces, 0.0)
    assert np.array_equal(panels.vertices, whole.vertices[original]) and len(panels.vertices) > len(whole.vertices)
    # every copy of an attachment vertex is attached, in the order of the whole garment's attachments
    assert np.array_equal(np.sort(panels.attachment), np.flatnonzero(np.isin(original, whole.attachment)))
    rank = np.argsort(whole.attachment)[np.searchsorted(whole.attachment[np.argsort(whole.attachment)],
                                                        original[panels.attachment])]
    assert np.all(np.diff(rank) >= 0)
    welded = panels.welded(1e-6)
    assert np.array_equal(welded.vertices, whole.vertices) and np.array_equal(welded.faces, whole.faces)
    assert np.array_equal(welded.attachment, whole.attachment)
    assert np.array_equal(welded.attachment_part, whole.attachment_part)


@pytest.mark.parametrize("kind", ["pants", "skirt"])
def test_the_waistband_is_one_panel_that_meets_itself_and_carries_every_pin(kind):
    g = make_garment(kind, SKEL, max_edge=0.15, panels=True)
    piece = pieces(g.vertices, g.faces)
    band = piece == piece[g.attachment[0]]
    assert np.all(band[g.attachment])
    assert len(np.unique(g.vertices[band], axis=0)) < band.sum(), "closed by a seam whose vertices are duplicated"


def test_scene_builders_cut_panels_and_weld_them_before_pins_and_skinning():
    settings = resolve_scene(CONFIG, "pants", "cpu")
    whole = build_rest(settings)
    cut = build_rest({**settings, "mesh": {**settings["mesh"], "panels": True}})
    assert len(cut.vertices) > len(whole.vertices) and len(cut.pin_ids) > len(whole.pin_ids)
    assert cut.skinning_weights.shape == (len(cut.vertices), whole.skinning_weights.shape[1])
    sewn = build_rest({**settings, "mesh": {**settings["mesh"], "panels": True, "weld": 1e-6}})
    for name in ("vertices", "faces", "pin_ids", "pin_part", "skinning_influences", "skinning_weights"):
        assert np.array_equal(getattr(sewn, name), getattr(whole, name)), name
    grid = resolve_scene(CONFIG, "flag", "cpu")
    assert np.array_equal(build_rest({**grid, "mesh": {**grid["mesh"], "weld": 1e-6}}).vertices,
                          build_rest(grid).vertices)
    with pytest.raises(ValueError, match="face"):     # a weld wider than the grid's edges leaves no mesh
        build_rest({**grid, "mesh": {**grid["mesh"], "weld": 0.5}})
