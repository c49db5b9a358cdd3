"""Hands written by the tests (of tests/scenes, tests/hostile and tests/pipeline): the procedural hand's own skin as
an OBJ and its skeleton as a bone file (scenes.hand_file's format), scaled, moved and in any unit, so that what the
hand_file generator makes of them can be compared with the procedural hand itself; and the workflow config that
shrinks the hand scene to seconds (`hand_config`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from scenes.capsules import capsules_world
from scenes.hand_file import LAYOUT
from scenes.hand_shape import procedural_hand
from scenes.hand_skeleton import hand_skeleton
from scenes.kinematics import rest_transforms

UNIT_METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
REPO = Path(__file__).resolve().parents[1]
FRAMES = 24
# A 12 mm hand (~1,500 skin vertices, ~2,900 tets), two training sequences and the held-out fist of FRAMES frames,
# a small decoder.
TINY_HAND = {"frames": FRAMES, "sequences": 2, "shard": 2, "mesh": {"skin_spacing": 0.012, "tet_spacing": 0.012},
             "network": {"arch": "U32 U U32 U16 U3"}, "operators": {"levels": 5}, "training": {"epochs": 10},
             "evaluation": {"render_frames": 1, "video_frames": 1, "export_frames": 1, "timing_frames": 3}}
SEQUENCES = ("train_000", "train_001", "held_out_000")


def hand_config(folder: Path, scenes: dict | None = None, **hand) -> Path:
    """hand.yaml in `folder`: the shipped config with the CPU profile's hand scene shrunk to TINY_HAND (its keys
    replaced by `hand`'s) and `scenes` added."""
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["hand"] = {**TINY_HAND, **hand}
    config["scenes"].update(scenes or {})
    path = folder / "hand.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def procedural_joints() -> dict[str, np.ndarray]:
    """The procedural skeleton's joints by role (metres): each part's joint, the forearm's a point down its stump
    (the procedural forearm turns on the wrist itself), and each fingertip's the centre of its last capsule's end."""
    skel = hand_skeleton()
    rotation, translation = rest_transforms(skel)
    a, b, _, _ = capsules_world(skel, (rotation, translation))
    joints = {name: translation[k] for k, name in enumerate(skel.names)}
    joints["forearm"] = a[skel.index("forearm")]
    for chain, last in (("thumb", "thumb_2"), ("index", "index_3"), ("middle", "middle_3"), ("ring", "ring_3"),
                        ("little", "little_3")):
        joints[f"{chain}_tip"] = b[skel.index(last)]
    return joints


def bone_document(joints: dict[str, np.ndarray], names: dict[str, str] | None = None) -> dict:
    """A bone file's document of role joints (scenes.hand_file.LAYOUT's tree), each joint called `names[role]`
    (default: the role) and listed under roles where that differs."""
    names = names or {}
    name = lambda role: names.get(role, role)  # noqa: E731
    listed = [{"name": name(role), "position": [float(c) for c in joints[role]],
               **({"parent": name(parent)} if parent else {})} for role, parent in LAYOUT.items()]
    document = {"joints": listed}
    if names:
        document["roles"] = dict(names)
    return document


def change_joints(document: dict, **change) -> dict:
    """A bone document (bone_document's form) with each named joint's fields updated, or the joint removed where
    its change is None: the same document, changed in place, for chaining."""
    joints = {j["name"]: j for j in document["joints"]}
    for name, fields in change.items():
        if fields is None:
            document["joints"].remove(joints[name])
        else:
            joints[name].update(fields)
    return document


def write_hand_files(folder: Path, spacing: float = 0.008, scale: float = 1.0, offset=(0.0, 0.0, 0.0),
                     units: str = "m", names: dict[str, str] | None = None) -> tuple[Path, Path]:
    """hand.obj (the procedural skin, meshed at `spacing`) and bones.yaml (its joints), both scaled by `scale`
    about the origin, moved by `offset` (metres) and written in `units`."""
    hand = procedural_hand(spacing, spacing)
    place = lambda x: (scale * np.asarray(x) + np.asarray(offset)) / UNIT_METRES[units]  # noqa: E731
    obj, bones = Path(folder) / "hand.obj", Path(folder) / "bones.yaml"
    write_obj(obj, place(hand.skin_vertices), hand.skin_faces)
    joints = {role: place(x) for role, x in procedural_joints().items()}
    bones.write_text(yaml.safe_dump(bone_document(joints, names), sort_keys=False, default_flow_style=None))
    return obj, bones


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist()))
