"""The procedural hand (scenes.hand_skeleton, scenes.hand_shape): its 18 angles and their limits, a closed
manifold skin on its implicit surface, a tet volume of measured quality that embeds the skin, bones that grip it,
fingers that are not glued together, and the FEM solver's fist and hyper-extension without an inverted tet."""
import numpy as np
import pytest

from geometry.isosurface import triangle_angles
from geometry.mesh import validate_mesh
from geometry.tets import dihedral_angles, radius_ratios, tet_volumes
from hand_fem import solve
from scenes.hand_shape import RestShapes, hand_sdf, procedural_hand
from scenes.hand_skeleton import ANGLE_LIMITS, ANGLE_NAMES, fist_angles, hand_transforms, part_angles

SPACING = 0.008     # the CI size: ~3.5k skin vertices, ~8k tets


@pytest.fixture(scope="module")
def hand():
    return procedural_hand(SPACING, SPACING)


def test_eighteen_angles_within_anatomical_limits_pose_the_parts_the_dips_following_their_pips(hand):
    skel = hand.skeleton
    assert len(ANGLE_NAMES) == 18 and (ANGLE_LIMITS[:, 0] <= 0).all() and (ANGLE_LIMITS[:, 1] > 0).all()
    angles = fist_angles(0.5)
    parts = part_angles(skel, angles)
    pip = angles[ANGLE_NAMES.index("middle_pip_flexion")]
    assert parts[skel.index("middle_2"), 0] == pip
    assert parts[skel.index("middle_3"), 0] == pytest.approx(2 / 3 * pip)
    assert (parts[skel.index("forearm")] == 0).all()
    too_far = np.zeros(18)
    too_far[ANGLE_NAMES.index("index_pip_flexion")] = np.radians(120)
    with pytest.raises(ValueError, match="'index_pip_flexion' outside its limits"):
        part_angles(skel, too_far)
    # Posed by the angles, a fingertip moves as forward kinematics says: flexing the MCP by 90 degrees turns the
    # whole finger to point along +z (towards the palm side).
    flexed = np.zeros(18)
    flexed[ANGLE_NAMES.index("middle_mcp_flexion")] = np.pi / 2
    rotation, translation = hand_transforms(skel, flexed)
    finger = translation[skel.index("middle_3")] - translation[skel.index("middle_1")]
    assert finger[2] > 0.04 and abs(finger[1]) < 1e-9


def test_the_skin_is_a_closed_manifold_on_the_implicit_surface_with_even_triangles(hand):
    vertices, faces = hand.skin_vertices, hand.skin_faces
    validate_mesh(vertices, faces)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    assert 2 * len(edges) == 3 * len(faces)                                     # closed: every edge in two faces
    assert len(vertices) - len(edges) + len(faces) == 2                         # genus 0
    assert 2_000 < len(vertices) < 6_000
    assert np.abs(hand_sdf(hand.skeleton, RestShapes.of(hand.skeleton), vertices)).max() < 1e-6
    v = vertices[faces]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
    assert 300e-6 < volume < 600e-6                                             # a hand and a wrist: ~0.45 l
    np.testing.assert_allclose(hand.skin_weights.sum(axis=1), 1.0)
    # Even triangles: marching tetrahedra alone leaves slivers (1% of its triangles under 1 degree at this size).
    smallest = triangle_angles(vertices, faces).min(axis=1)
    assert smallest.min() > 5 and np.percentile(smallest, 1) > 20


def test_the_volume_is_of_congruent_tets_and_embeds_the_skin(hand):
    vol = hand.volume
    assert (tet_volumes(vol.nodes, vol.tets) > 0).all()
    assert vol.min_dihedral_deg == pytest.approx(dihedral_angles(vol.nodes, vol.tets).min()) == pytest.approx(45.0)
    assert vol.min_radius_ratio == pytest.approx(radius_ratios(vol.nodes, vol.tets).min()) == pytest.approx(0.7174,
                                                                                                         abs=1e-4)
    tet_of, weights = vol.embedding
    assert weights.min() > -1e-9
    embedded = np.einsum("sk,skj->sj", weights, vol.nodes[vol.tets[tet_of]])
    np.testing.assert_allclose(embedded, hand.skin_vertices, atol=1e-12)
    assert set(np.unique(vol.driven_part)) == set(range(hand.skeleton.n_parts))  # every bone grips the flesh


@pytest.mark.parametrize("pose", ["fist", "hyper-extension"])
def test_a_tight_fist_and_a_hyper_extension_invert_no_tet(hand, pose):
    end = fist_angles(1.0) if pose == "fist" else ANGLE_LIMITS[:, 0]
    solver = solve(hand, [end * f / 6 for f in range(1, 7)])
    x = solver.state.read_nodes()[0]
    assert tet_volumes(x, hand.volume.tets).min() > 0
    skin = solver.state.read_world_positions()[0]
    lbs = hand.skinned(hand_transforms(hand.skeleton, end))
    # The flesh follows the bones: within a centimetre of the skinned skin (LBS's own errors at the knuckles).
    assert np.linalg.norm(skin - lbs, axis=1).max() < 0.02
    assert np.linalg.norm(skin - hand.skin_vertices, axis=1).max() > 0.05      # and it did move


def test_neighbouring_fingers_are_not_glued_by_the_grid(hand):
    """Bending the index finger alone leaves the middle finger's skin where it was."""
    angles = np.zeros(18)
    angles[ANGLE_NAMES.index("index_mcp_flexion")] = np.radians(80)
    solver = solve(hand, [angles / 2, angles])
    skin = solver.state.read_world_positions()[0]
    skel = hand.skeleton
    on_middle = np.isin(hand.skin_influences, [skel.index(f"middle_{k}") for k in (1, 2, 3)])
    middle = (hand.skin_weights * on_middle).sum(axis=1) > 0.99            # the middle finger's skin
    assert middle.sum() > 150
    # Glued at the nodes the grid's tets share between the fingers, it would follow the index by ~13 mm.
    assert np.linalg.norm(skin[middle] - hand.skin_vertices[middle], axis=1).max() < 0.002


@pytest.mark.parametrize("spacings", [(0.0, 0.008), (0.008, 0.03), (float("nan"), 0.008), (0.008, 0.001)])
def test_spacings_a_hand_cannot_be_meshed_at_are_refused(spacings):
    with pytest.raises(ValueError, match="spacing .* is outside"):
        procedural_hand(*spacings)
