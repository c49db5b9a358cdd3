"""A user's own hand (`mesh.generator: hand_file`): a closed skin from a mesh file and the joints of a bone file,
made the hand the FEM moves exactly as the procedural one is (scenes.hand_shape: the Kuhn grid clipped to the
skin, the chains split apart, the nodes within each bone driven by it, the skin embedded and skinned). Arrays and
parsed documents in, a `Hand` out: the files are read by the hand_scene stage.

The bone file (YAML or JSON) lists joints, each a name, a position (the mesh file's units and frame) and a parent
(none for the one root), and may map roles onto them:

    joints:
      - {name: elbow, position: [0, -7, 0]}
      - {name: wrist, position: [0, 0, 0], parent: elbow}
      - ...
    roles: {forearm: elbow, palm: wrist}     # a role left out is played by the joint of its own name

The roles are the 17 parts of scenes.hand_skeleton, each the joint where that part turns on its parent (`forearm`: a
point in the forearm stump, below `palm`, the wrist), and one tip joint per finger and thumb (`index_tip`, ...:
inside the fingertip), so the 18 joint angles act on the user's joints as on the procedural hand's. A role's
joint must descend from its layout parent's joint (`index_2` from `index_1`); joints between them, and joints no
role names, are allowed and ignored. Each part's bone runs from its joint to its child's (the palm's to the middle
finger's MCP, plus three more from the wrist to the other MCPs, its metacarpals); its flesh radius at each end is
the distance from that joint to the skin. Its frame has y along the bone and z towards the palm (the normal of
the index-to-little and wrist-to-middle directions), the thumb's turned THUMB_TWIST about its bone as the
procedural thumb's, so flexion bends every finger towards the palm. That normal makes the hand a right hand: a
left hand is mirrored first (x -> -x in both files).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
from scipy.spatial.transform import Rotation

from geometry.mesh import boundary_loops, unique_edges, validate_mesh
from geometry.solid import distance_to_mesh, inside_mesh
from scenes.garment_file import UNITS, detect_units
from scenes.hand_shape import Hand, RestShapes, check_spacing, flesh_hand
from scenes.hand_skeleton import FINGERS, THUMB_TWIST, hand_skeleton
from scenes.skeleton import Skeleton

HAND_SIZE = (0.15, 0.35)   # metres: a hand with a forearm stump, wrist stump to fingertip (cm and in don't overlap)
MAX_JOINTS = 1000          # a hand rig has ~25; a bone file of more is no hand's
MAX_NAME = 100             # characters of a joint's name (names are quoted in errors, which are one line)
BONE_SAMPLES = 5           # points along each bone checked to lie inside the skin
MAX_TAPER = 0.9            # a bone's end radii differ by at most this share of its length (a capsule needs < 1)


def _layout() -> dict[str, str | None]:
    """Each role's layout parent: the procedural skeleton's parts, and a tip after each part that ends a chain."""
    skel = hand_skeleton()
    parents = {name: (None if p < 0 else skel.names[p]) for name, p in zip(skel.names, skel.parents)}
    ends = set(skel.names) - {parent for parent in parents.values() if parent}
    return {**parents, **{f"{name.rsplit('_', 1)[0]}_tip": name for name in sorted(ends)}}


LAYOUT = _layout()


def _bones() -> list[tuple[str, str, str]]:
    """(part, start role, end role) of every bone: each part's from its joint to its child's (the palm's to the
    middle finger's MCP), then the palm's other metacarpals."""
    child = {parent: role for role, parent in LAYOUT.items() if parent is not None}
    ends = {**child, "palm": "middle_1"}          # the palm, the one part with several children, set apart
    return ([(part, part, ends[part]) for part in hand_skeleton().names]
            + [("palm", "palm", f"{finger}_1") for finger in FINGERS if finger != "middle"])


BONES = _bones()


@dataclass(frozen=True, eq=False)
class Rig:
    """A bone file's roles: each role's position (metres once `in_metres`) and the file's name of its joint."""
    positions: dict[str, np.ndarray]
    joints: dict[str, str]

    def in_metres(self, factor: float) -> "Rig":
        return Rig({role: factor * p for role, p in self.positions.items()}, self.joints)


def read_rig(document: Any) -> Rig:
    """The roles of a parsed bone file; ValueError naming the first problem (a joint, a parent, a role)."""
    if not isinstance(document, Mapping) or not isinstance(document.get("joints"), list) \
            or set(document) - {"joints", "roles"}:
        raise ValueError("a bone file maps 'joints' to a list of joints ({name, position, parent}) and optionally "
                         "'roles' to the joints that play them")
    joints = document["joints"]
    if not 0 < len(joints) <= MAX_JOINTS:
        raise ValueError(f"{len(joints)} joints: a hand's bone file lists 1 to {MAX_JOINTS}")
    position, parent = {}, {}
    for k, joint in enumerate(joints):
        if not isinstance(joint, Mapping) or set(joint) - {"name", "position", "parent"} \
                or not isinstance(joint.get("name"), str) or not 0 < len(joint["name"]) <= MAX_NAME \
                or not joint["name"].isprintable():
            raise ValueError(f"joint {k}: a joint is {{name, position, parent}}, its name 1 to {MAX_NAME} printable "
                             f"characters")
        name = joint["name"]
        if name in position:
            raise ValueError(f"joint '{name}' is listed twice")
        xyz = joint.get("position")
        if not (isinstance(xyz, list) and len(xyz) == 3 and all(
                isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in xyz)):
            # Not quoted: an alias may stand for a structure far too big to print.
            raise ValueError(f"joint '{name}': position must be three finite numbers [x, y, z]")
        if not (joint.get("parent") is None or isinstance(joint["parent"], str)):
            raise ValueError(f"joint '{name}': parent must be a joint's name or absent")
        position[name], parent[name] = np.array(xyz, dtype=np.float64), joint.get("parent")
    ancestors = _ancestors(parent)
    roles = document.get("roles") or {}
    if not isinstance(roles, Mapping):
        raise ValueError("'roles' maps roles to the file's joint names")
    for role, name in roles.items():
        if role not in LAYOUT:
            raise ValueError(f"roles: unknown role {str(role)[:80]!r} (roles: {', '.join(LAYOUT)})")
        if not isinstance(name, str) or name not in position:
            raise ValueError(f"roles: role '{role}' names no joint the file lists")
    of = {role: roles.get(role, role) for role in LAYOUT}
    missing = [role for role, name in of.items() if name not in position]
    if missing:
        raise ValueError(f"missing joint '{of[missing[0]]}' (role {missing[0]}): name a joint so, or map the role "
                         f"to one of the file's joints under 'roles'")
    shared = {name for name in of.values() if list(of.values()).count(name) > 1}
    if shared:
        name = sorted(shared)[0]
        raise ValueError(f"joint '{name}' plays several roles ({', '.join(r for r in of if of[r] == name)})")
    for role, layout_parent in LAYOUT.items():
        if layout_parent is not None and of[layout_parent] not in ancestors[of[role]]:
            raise ValueError(f"joint '{of[role]}' (role {role}) does not descend from joint '{of[layout_parent]}' "
                             f"(role {layout_parent})")
    return Rig({role: position[name] for role, name in of.items()}, of)


def _ancestors(parent: dict[str, str | None]) -> dict[str, set[str]]:
    """Each joint's ancestors; ValueError for an unknown parent, no root or several, or a cycle."""
    for name, p in parent.items():
        if p is not None and p not in parent:
            raise ValueError(f"joint '{name}': parent {p[:MAX_NAME]!r} is no joint of the file")
    roots = [name for name, p in parent.items() if p is None]
    if len(roots) != 1:
        raise ValueError(f"{len(roots)} joints have no parent ({', '.join(roots[:5]) or 'none'}): a hand's joints "
                         f"form one tree from one root")
    ancestors: dict[str, set[str]] = {roots[0]: set()}
    for name in parent:
        chain = []
        while name not in ancestors:
            if name in chain:
                cycle = chain[chain.index(name):]
                raise ValueError(f"joints {', '.join(repr(c) for c in cycle[:5])} form a cycle of parents")
            chain.append(name)
            name = parent[name]
        for joint in reversed(chain):
            ancestors[joint] = ancestors[name] | {name}
            name = joint
    return ancestors


@dataclass(frozen=True, eq=False)
class FileSkin:
    """A hand file's skin in metres, outward: vertices (V, 3), faces (F, 3), the units read or given."""
    vertices: np.ndarray
    faces: np.ndarray
    units: str


def skin_from_file(vertices: np.ndarray, faces: np.ndarray, units: str) -> FileSkin:
    """The file's mesh in metres, wound outwards; ValueError for one that bounds no solid (open, several pieces,
    non-manifold) or has no hand's size in `units` (auto: the one unit that gives a hand's)."""
    faces = np.asarray(faces, dtype=np.int64)
    validate_mesh(vertices, faces)
    holes = boundary_loops(len(vertices), faces)
    if holes:
        raise ValueError(f"not closed: {len(holes)} hole(s), the first along {len(holes[0])} edges; a hand's skin is "
                         f"a closed surface (a forearm stump capped)")
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    pieces = csgraph.connected_components(graph, directed=False)[0]
    if pieces > 1:
        raise ValueError(f"{pieces} separate pieces: a hand's skin is one closed surface")
    units = detect_units(vertices, units, HAND_SIZE, "hand")
    metres = np.asarray(vertices, dtype=np.float64) * UNITS[units]
    tri = metres[faces]
    if np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:
        faces = faces[:, ::-1].copy()            # wound inwards: the skin's normals point out
    return FileSkin(metres, faces, units)


def rig_skeleton(skin: FileSkin, rig: Rig) -> tuple[Skeleton, RestShapes]:
    """The procedural skeleton's parts, limits and angles on the rig's joints (metres), and the capsules of its
    flesh; ValueError naming the first joint or bone outside the skin, or a bone that has no frame."""
    _check_inside(skin, rig)
    return _skeleton(skin, rig)


def _check_inside(skin: FileSkin, rig: Rig) -> None:
    """Every role's joint and every bone inside the skin; ValueError naming the first that is not."""
    roles = list(rig.positions)
    inside = inside_mesh(skin.vertices, skin.faces, np.array([rig.positions[r] for r in roles]))
    if not inside.all():
        role = roles[int(np.argmin(inside))]
        raise ValueError(f"joint '{rig.joints[role]}' (role {role}) lies outside the hand's skin")
    for part, start, end in BONES:
        t = np.linspace(0, 1, BONE_SAMPLES + 2)[1:-1, None]
        along = (1 - t) * rig.positions[start] + t * rig.positions[end]
        if not inside_mesh(skin.vertices, skin.faces, along).all():
            raise ValueError(f"the {part} bone from joint '{rig.joints[start]}' to '{rig.joints[end]}' leaves the "
                             f"hand's skin")


def file_hand(skin: FileSkin, skeleton: tuple[Skeleton, RestShapes], tet_spacing: float) -> Hand:
    """The hand of a skin and its rig's skeleton (rig_skeleton) with its volume at `tet_spacing`; ValueError for a
    spacing a hand cannot be meshed at."""
    check_spacing("tet spacing", tet_spacing)
    vertices, faces = skin.vertices, skin.faces
    return flesh_hand(*skeleton, vertices, faces, tet_spacing, lambda p: inside_mesh(vertices, faces, p),
                      (vertices.min(axis=0), vertices.max(axis=0)))


def _skeleton(skin: FileSkin, rig: Rig) -> tuple[Skeleton, RestShapes]:
    """The layout's parts on the rig: each part's frame (y along its bone, z towards the palm, the thumb's
    twisted), its joint in its parent's frame, its bone and the flesh's radius at the bone's ends."""
    layout = hand_skeleton()
    p = rig.positions
    normal = np.cross(p["index_1"] - p["little_1"], p["middle_1"] - p["palm"])
    if not np.linalg.norm(normal) > 1e-9:
        raise ValueError("the index and little MCPs and the line from the wrist to the middle MCP are parallel: "
                         "the palm has no facing")
    normal /= np.linalg.norm(normal)
    ends = np.array([(p[start], p[end]) for _, start, end in BONES])                     # (C, 2, 3)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    for k, (part, start, end) in enumerate(BONES):
        if not length[k] > 1e-6 * np.ptp(skin.vertices, axis=0).max():
            raise ValueError(f"the {part} bone from joint '{rig.joints[start]}' to '{rig.joints[end]}' has no length")
    radius = dict(zip(p, distance_to_mesh(skin.vertices, skin.faces, np.array(list(p.values())))))
    ra = np.array([radius[start] for _, start, _ in BONES])
    rb = np.clip([radius[end] for _, _, end in BONES], ra - MAX_TAPER * length, ra + MAX_TAPER * length)
    rotation = np.empty((layout.n_parts, 3, 3))
    for k, name in enumerate(layout.names):
        y = (ends[k, 1] - ends[k, 0]) / length[k]
        z = normal - normal @ y * y
        if not np.linalg.norm(z) > 1e-6:
            raise ValueError(f"the {name} bone from joint '{rig.joints[BONES[k][1]]}' to "
                             f"'{rig.joints[BONES[k][2]]}' points along the palm's normal: it has no flexion axis")
        z /= np.linalg.norm(z)
        if name.startswith("thumb"):
            twist = np.radians(THUMB_TWIST)
            z = np.cos(twist) * z + np.sin(twist) * np.cross(y, z)
        rotation[k] = np.stack([np.cross(y, z), y, z], axis=1)
    parents = layout.parents
    local = np.array([rotation[k] if q < 0 else rotation[q].T @ rotation[k] for k, q in enumerate(parents)])
    offsets = np.array([p[name] if q < 0 else rotation[q].T @ (p[name] - p[layout.names[q]])
                        for name, q in zip(layout.names, parents)])
    n = layout.n_parts
    skel = Skeleton(names=layout.names, parents=parents, joint_offsets=offsets,
                    frame_rotations=Rotation.from_matrix(local).as_quat(), capsule_a=np.zeros((n, 3)),
                    capsule_b=np.stack([np.zeros(n), length[:n], np.zeros(n)], 1), radius_a=ra[:n],
                    radius_b=rb[:n], joint_lower=layout.joint_lower, joint_upper=layout.joint_upper,
                    height=float(np.ptp(skin.vertices, axis=0).max()))
    part = np.array([layout.index(name) for name, _, _ in BONES])
    return skel, RestShapes(ends[:, 0], ends[:, 1], ra, rb, part)
