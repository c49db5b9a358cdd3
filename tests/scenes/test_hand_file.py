"""A user's own hand (scenes.hand_file): the procedural hand's skin written as an OBJ and its skeleton as a bone
file (tests/hand_files.py) make the procedural hand again (its tets, the nodes each bone drives, its motion under
the 18 angles and its FEM fist), wherever the files put it and in whatever unit; a real rig's names mapped by
roles with joints between them make the same hand; a bone file that is no tree of the hand's roles is refused
naming the joint."""
import numpy as np
import pytest
import yaml
from scipy.spatial import cKDTree

from geometry.tets import tet_volumes
from hand_fem import solve
from hand_files import bone_document, change_joints, procedural_joints, write_hand_files
from pipeline.core.meshio import load_mesh
from scenes.garment_file import UNITS
from scenes.hand_file import LAYOUT, file_hand, read_rig, rig_skeleton, skin_from_file
from scenes.hand_shape import procedural_hand
from scenes.hand_skeleton import ANGLE_NAMES, fist_angles, hand_transforms

SPACING = 0.008


def hand_of_files(obj, bones, units="auto", spacing=SPACING):
    skin = skin_from_file(*load_mesh(obj), units)
    rig = read_rig(yaml.safe_load(bones.read_text())).in_metres(UNITS[skin.units])
    return file_hand(skin, rig_skeleton(skin, rig), spacing), skin.units


@pytest.fixture(scope="module")
def procedural():
    return procedural_hand(SPACING, SPACING)


@pytest.fixture(scope="module")
def own(tmp_path_factory):
    return hand_of_files(*write_hand_files(tmp_path_factory.mktemp("own"), SPACING))[0]


def test_the_procedural_hands_own_files_make_its_volume_and_driven_nodes_again(procedural, own):
    ours, theirs = own.volume, procedural.volume
    np.testing.assert_array_equal(own.skin_faces, procedural.skin_faces)
    assert (tet_volumes(ours.nodes, ours.tets) > 0).all() and ours.min_dihedral_deg == pytest.approx(45.0)
    # The skin is the polyhedron inscribed in the procedural hand's implicit surface: a little less flesh.
    volume = [tet_volumes(v.nodes, v.tets).sum() for v in (ours, theirs)]
    assert 0.96 < volume[0] / volume[1] <= 1.0
    assert abs(len(ours.tets) / len(theirs.tets) - 1) < 0.03
    assert abs(ours.split_nodes - theirs.split_nodes) <= 0.1 * theirs.split_nodes
    embedded = np.einsum("sk,skj->sj", ours.embedding[1], ours.nodes[ours.tets[ours.embedding[0]]])
    np.testing.assert_allclose(embedded, own.skin_vertices, atol=1e-12)
    # Every bone drives about as many nodes, each within a grid diagonal of one the procedural bone drives.
    counts = [np.bincount(v.driven_part, minlength=17) for v in (ours, theirs)]
    assert (counts[0] >= 6).all() and np.abs(counts[0] - counts[1]).max() <= 3
    for part in range(17):
        near = cKDTree(theirs.nodes[theirs.driven[theirs.driven_part == part]])
        assert near.query(ours.nodes[ours.driven[ours.driven_part == part]])[0].max() <= np.sqrt(3) * SPACING


def test_the_angles_move_its_parts_as_the_procedural_ones(procedural, own):
    angles = fist_angles(0.8)
    ours, theirs = hand_transforms(own.skeleton, angles), hand_transforms(procedural.skeleton, angles)
    # Every joint where the procedural hand has it (the forearm's own joint is a point down the stump instead)...
    np.testing.assert_allclose(ours[1][1:], theirs[1][1:], atol=1e-12)
    # ... and every finger's and the thumb's frame too: their bones, their palm's side and the thumb's twist are
    # the procedural hand's. The palm's bone runs to the middle MCP, 2.5 degrees off the procedural palm's y.
    np.testing.assert_allclose(np.abs(np.einsum("pk,pk->p", ours[0][2:], theirs[0][2:])), 1.0, atol=1e-12)
    wrist = np.zeros(18)
    wrist[ANGLE_NAMES.index("wrist_flexion")] = np.radians(60)
    fingertip = hand_transforms(own.skeleton, wrist)[1][own.skeleton.index("middle_3")]
    assert fingertip[2] > 0.08                                   # flexion bends towards the palm (+z)


def test_its_fem_fist_is_the_procedural_hands(procedural, own):
    poses = [fist_angles(0.7) * k / 2 for k in (1, 2)]
    ours, theirs = (solve(hand, poses).state.read_world_positions()[0] for hand in (own, procedural))
    gap = np.linalg.norm(ours - theirs, axis=1)
    assert gap.mean() < 0.002 and gap.max() < 0.01               # against ~6 cm that the fingertips move
    assert np.linalg.norm(theirs - procedural.skin_vertices, axis=1).max() > 0.05


def test_a_scaled_moved_hand_in_centimetres_is_the_same_hand_scaled_and_moved(tmp_path, own):
    moved, units = hand_of_files(*write_hand_files(tmp_path, SPACING, offset=(0.3, -1.2, 0.05), units="cm"))
    assert units == "cm"
    # The grid follows the skin's box: the same nodes and tets, moved.
    np.testing.assert_array_equal(moved.volume.tets, own.volume.tets)
    np.testing.assert_allclose(moved.volume.nodes - (0.3, -1.2, 0.05), own.volume.nodes, atol=1e-9)
    np.testing.assert_array_equal(moved.volume.driven, own.volume.driven)
    posed = [hand_transforms(hand.skeleton, fist_angles(0.5)) for hand in (moved, own)]
    np.testing.assert_allclose(moved.driven_targets(posed[0]) - (0.3, -1.2, 0.05), own.driven_targets(posed[1]),
                               atol=1e-9)
    # Skinning binds a vertex to its nearest bone: a few vertices halfway between two change sides at rounding.
    np.testing.assert_allclose(moved.skinned(posed[0]) - (0.3, -1.2, 0.05), own.skinned(posed[1]), atol=1e-3)
    big, units = hand_of_files(*write_hand_files(tmp_path, SPACING, scale=1.25, units="mm"))
    assert units == "mm"
    ratio = tet_volumes(big.volume.nodes, big.volume.tets).sum() / tet_volumes(own.volume.nodes,
                                                                           own.volume.tets).sum()
    # The flesh grows as the cube of the scale, the shell of tets beyond the skin (up to a tet thick) as its square.
    assert 1.25 ** 2 < ratio < 1.25 ** 3
    assert (np.bincount(big.volume.driven_part, minlength=17) >= 6).all()


def test_a_rigs_own_names_and_joints_between_the_roles_make_the_same_hand(tmp_path, own):
    names = {role: f"Bone.{k:02d}.R" for k, role in enumerate(LAYOUT)}
    obj, bones = write_hand_files(tmp_path, SPACING, names=names)
    document = yaml.safe_load(bones.read_text())
    # A carpal joint between the wrist and the index MCP, and a helper joint no role names.
    joints = {j["name"]: j for j in document["joints"]}
    index_mcp = joints[names["index_1"]]
    document["joints"] += [{"name": "carpal", "position": [0.01, 0.03, 0.0], "parent": names["palm"]},
                           {"name": "ik_target", "position": [0.0, 0.05, 0.0], "parent": names["forearm"]}]
    index_mcp["parent"] = "carpal"
    bones.write_text(yaml.safe_dump(document))
    renamed, _ = hand_of_files(obj, bones)
    np.testing.assert_array_equal(renamed.volume.driven, own.volume.driven)
    np.testing.assert_allclose(renamed.skeleton.joint_offsets, own.skeleton.joint_offsets, atol=1e-12)


def document(**change):
    return change_joints(bone_document(procedural_joints()), **change)


@pytest.mark.parametrize("doc, message", [
    (document(index_2={"parent": "index_3"}), r"joints 'index_2', 'index_3' form a cycle of parents"),
    (document(index_2={"parent": "index_9"}), r"joint 'index_2': parent 'index_9' is no joint of the file"),
    (document(ring_tip=None), r"missing joint 'ring_tip' \(role ring_tip\)"),
    (document(palm={"position": [0.0, float("nan"), 0.0]}), r"joint 'palm': position must be three finite"),
    (document(thumb_1={"parent": "palm"}), r"joint 'thumb_1' \(role thumb_1\) does not descend from joint "
                                           r"'thumb_0'"),
    (document(palm={"parent": None}), r"2 joints have no parent"),
    ({"joints": [], "roles": {}}, "0 joints"),
    ([1, 2], "a bone file maps 'joints'"),
    ({**document(), "roles": {"pinky": "little_1"}}, "unknown role 'pinky'"),
    ({**document(), "roles": {"little_1": "ring_1"}}, r"joint 'ring_1' plays several roles"),
], ids=["cycle", "unknown parent", "missing", "nan", "descent", "two roots", "empty", "no map", "role", "shared"])
def test_a_bone_file_that_is_no_tree_of_the_hands_roles_is_refused_naming_the_joint(doc, message):
    with pytest.raises(ValueError, match=message):
        read_rig(doc)


@pytest.mark.parametrize("role, moved_to, message", [
    ("index_2", "index_1", "the index_1 bone from joint 'index_1' to 'index_2' has no length"),
    ("little_1", "palm", "the palm bone from joint 'palm' to 'little_1' has no length"),
], ids=["phalanx", "metacarpal"])
def test_a_rig_whose_bones_have_no_frame_is_refused_naming_the_bone(tmp_path, role, moved_to, message):
    obj, _ = write_hand_files(tmp_path, SPACING)
    joints = procedural_joints()
    joints[role] = joints[moved_to]
    skin = skin_from_file(*load_mesh(obj), "m")
    with pytest.raises(ValueError, match=message):
        rig_skeleton(skin, read_rig(bone_document(joints)))
