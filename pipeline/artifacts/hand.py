"""The hand scene's artifacts (docs/artifacts.md, sections "hand.h5" and "fem.h5"):

- hand.h5, written by `pipeline.hand_scene`: the hand's rest skin (`vertices`, `faces` at the root, so any stage
  that reads a mesh reads it: the operators), its linear blend skinning weights, its tet volume (nodes, tets, the
  nodes each bone drives, the skin's barycentric embedding, the nodes' own skinning weights) with its element
  quality, and its skeleton's rest geometry: the procedural hand's, or a user's hand's (scenes.hand_file), whose
  joints and bones are its own while its 17 parts, their tree and the 18 angles' limits are the procedural
  layout's (scenes.hand_skeleton), checked on reading. A file written before user hands stores the part names and
  joint offsets alone: the procedural skeleton's, checked against it.
- fem.h5, written by `pipeline.hand_simulate`: one sequence's 18 joint angles per frame and the skin the FEM
  moved there, with how each frame's minimisation went (residual, Newton and CG iterations, converged) and its
  milliseconds.
"""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import h5py
import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, dataset, mesh_fingerprint, open_artifact, read, read_indices
from scenes.hand_shape import Hand, HandVolume
from scenes.hand_skeleton import ANGLE_NAMES, hand_skeleton
from scenes.sequences import is_hand
from scenes.skeleton import Skeleton

HAND_STAGE, RUN_STAGE = "hand_scene", "hand_simulate"
VERTICES, FACES = "vertices", "faces"
SKIN_INFLUENCES, SKIN_WEIGHTS = "skin/influences", "skin/weights"
NODES, TETS, DRIVEN, DRIVEN_PART = "volume/nodes", "volume/tets", "volume/driven", "volume/driven_part"
EMBED_TET, EMBED_WEIGHTS = "volume/embedding_tet", "volume/embedding_weights"
NODE_INFLUENCES, NODE_WEIGHTS = "volume/node_influences", "volume/node_weights"
PART_NAMES, JOINT_OFFSETS = "skeleton/names", "skeleton/joint_offsets"
# The rest of a Skeleton's rest geometry (its limits are the layout's): skeleton/<field>.
SKELETON_FIELDS = ("parents", "frame_rotations", "capsule_a", "capsule_b", "radius_a", "radius_b")
QUALITY = ("min_dihedral_deg", "min_radius_ratio", "split_nodes")      # attrs of volume/
ANGLES, SKIN, RESIDUAL, NEWTON, CG, CONVERGED, SOLVE_MS = (
    "angles", "skin", "residual", "newton_iterations", "cg_iterations", "converged", "solve_ms")


def check_hand_scene(settings: Mapping[str, Any], source: str) -> None:
    """An error naming `source` for the settings of a scene that is no hand scene."""
    if not is_hand(settings):
        raise PipelineError(f"{source}: scene '{settings['scene']}' is no hand scene (mesh.generator "
                            f"'{settings['mesh']['generator']}')")


def write_hand(path: str | os.PathLike, config: Mapping[str, Any], hand: Hand,
               attrs: Mapping[str, Any] | None = None) -> None:
    """hand.h5 of `hand`, with `attrs` (a user's hand: its files, their sha256, units) at the root."""
    vol = hand.volume
    with atomic_h5(path, HAND_STAGE, config) as f:
        f.attrs[SOURCE_MESH] = mesh_fingerprint(hand.skin_vertices, hand.skin_faces)
        f.attrs.update(attrs or {})
        for name, data in ((VERTICES, hand.skin_vertices), (FACES, hand.skin_faces.astype(np.int32)),
                           (SKIN_INFLUENCES, hand.skin_influences.astype(np.int32)),
                           (SKIN_WEIGHTS, hand.skin_weights), (NODES, vol.nodes), (TETS, vol.tets.astype(np.int32)),
                           (DRIVEN, vol.driven.astype(np.int32)), (DRIVEN_PART, vol.driven_part.astype(np.int32)),
                           (EMBED_TET, vol.embedding[0].astype(np.int32)), (EMBED_WEIGHTS, vol.embedding[1]),
                           (NODE_INFLUENCES, vol.node_influences.astype(np.int32)),
                           (NODE_WEIGHTS, vol.node_weights),
                           (PART_NAMES, np.array(hand.skeleton.names, dtype="S")),
                           (JOINT_OFFSETS, hand.skeleton.joint_offsets),
                           *((f"skeleton/{field}", getattr(hand.skeleton, field)) for field in SKELETON_FIELDS)):
            f.create_dataset(name, data=data)
        f[VERTICES].attrs["meaning"] = "the rest skin (S, 3), metres: the mesh the decoder writes"
        f[SKIN_WEIGHTS].attrs["meaning"] = ("linear blend skinning of the skin: 4 parts (skin/influences) and "
                                            "weights per vertex, rows summing to 1")
        f[DRIVEN].attrs["meaning"] = "the nodes within a bone, moved rigidly by the part volume/driven_part"
        f[EMBED_TET].attrs["meaning"] = ("the tet holding each skin vertex; volume/embedding_weights its "
                                         "barycentric weights: the skin follows the tets")
        f["volume"].attrs.update({name: getattr(vol, name) for name in QUALITY})
        f["volume"].attrs["meaning"] = ("Kuhn-grid tets clipped to the flesh (scenes/hand_shape.py); quality attrs: "
                                        "least dihedral angle (degrees), least radius ratio, node copies that keep "
                                        "the fingers apart")


def read_hand(path: str | os.PathLike) -> Hand:
    """The hand of a hand.h5, every index checked against what it indexes; one error naming the file otherwise."""
    with open_artifact(path) as f:
        skeleton = _read_skeleton(f, path)
        parts = skeleton.n_parts
        vertices = read(f, VERTICES, np.float64)
        nodes = read(f, NODES, np.float64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or nodes.ndim != 2 or nodes.shape[1] != 3:
            raise PipelineError(f"{path}: '{VERTICES}' {vertices.shape} and '{NODES}' {nodes.shape} must be (N, 3)")
        n_skin, n_nodes = len(vertices), len(nodes)
        faces = read_indices(f, FACES, n_skin, shape=(None, 3))
        tets = read_indices(f, TETS, n_nodes, shape=(None, 4))
        driven = read_indices(f, DRIVEN, n_nodes, shape=(None,))
        driven_part = read_indices(f, DRIVEN_PART, parts, shape=(len(driven),))
        embed_tet = read_indices(f, EMBED_TET, len(tets), shape=(n_skin,))
        skin_influences = read_indices(f, SKIN_INFLUENCES, parts, shape=(n_skin, 4))
        node_influences = read_indices(f, NODE_INFLUENCES, parts, shape=(n_nodes, 4))
        weights = {name: read(f, name, np.float64) for name in (EMBED_WEIGHTS, SKIN_WEIGHTS, NODE_WEIGHTS)}
        for name, rows in ((EMBED_WEIGHTS, n_skin), (SKIN_WEIGHTS, n_skin), (NODE_WEIGHTS, n_nodes)):
            w = weights[name]
            if w.shape != (rows, 4) or not np.allclose(w.sum(axis=1), 1.0, atol=1e-6):
                raise PipelineError(f"{path}: '{name}' must be ({rows}, 4) weights summing to 1 per row")
        quality = {name: f["volume"].attrs.get(name) for name in QUALITY}
        if any(value is None for value in quality.values()):
            raise PipelineError(f"{path}: 'volume' lacks the quality attrs {', '.join(QUALITY)}")
    volume = HandVolume(nodes, tets, driven, driven_part, (embed_tet, weights[EMBED_WEIGHTS]), node_influences,
                        weights[NODE_WEIGHTS], float(quality["min_dihedral_deg"]),
                        float(quality["min_radius_ratio"]), int(quality["split_nodes"]))
    return Hand(skeleton, vertices, faces, skin_influences, weights[SKIN_WEIGHTS], volume)


def _read_skeleton(f: h5py.File, path: str | os.PathLike) -> Skeleton:
    """The skeleton of a hand.h5: the procedural layout's parts, tree and limits on the stored rest geometry."""
    layout = hand_skeleton()
    names = tuple(n.decode() for n in read(f, PART_NAMES))
    offsets = read(f, JOINT_OFFSETS, np.float64)
    if names != layout.names:
        raise PipelineError(f"{path}: made for another skeleton than scenes.hand_skeleton's 17 parts")
    if "skeleton/frame_rotations" not in f:         # written before user hands: the procedural skeleton
        if offsets.shape != layout.joint_offsets.shape or not np.allclose(offsets, layout.joint_offsets):
            raise PipelineError(f"{path}: made for another skeleton than scenes.hand_skeleton's")
        return layout
    fields = {name: read(f, f"skeleton/{name}", np.int64 if name == "parents" else np.float64)
              for name in SKELETON_FIELDS}
    if not np.array_equal(fields["parents"], layout.parents):
        raise PipelineError(f"{path}: 'skeleton/parents' is not the tree of scenes.hand_skeleton's parts")
    try:
        return dataclasses.replace(layout, joint_offsets=offsets, **fields)
    except ValueError as err:
        raise PipelineError(f"{path}: skeleton: {err}") from None


def read_skin_vertex_count(path: str | os.PathLike) -> int:
    """The skin's vertex count from the shape of `vertices` alone (what a frame of the runs weighs)."""
    with open_artifact(path) as f:
        shape = f[VERTICES].shape if isinstance(f.get(VERTICES), h5py.Dataset) else ()
    if len(shape) != 2 or shape[1] != 3 or not 0 < shape[0] < 2 ** 31:
        raise PipelineError(f"{path}: '{VERTICES}' must be (S, 3) skin vertices, got {shape}")
    return int(shape[0])


@dataclasses.dataclass(frozen=True)
class HandRun:
    """One sequence's FEM run: per frame its angles (F, 18), the skin (F, S, 3) float32, the final residual, the
    Newton and CG iterations, whether it converged, and the batch's milliseconds over its worlds (frame 0: the
    rest state, not solved: 0)."""
    angles: np.ndarray
    skin: np.ndarray | None  # None: read without it (read_hand_run(..., skin=False))
    residual: np.ndarray
    newton_iterations: np.ndarray
    cg_iterations: np.ndarray
    converged: np.ndarray
    solve_ms: np.ndarray
    worlds: int              # sequences stepped together (solve_ms is the batch's over this)
    device: str


def write_hand_run(path: str | os.PathLike, config: Mapping[str, Any], run: HandRun, source_mesh: str) -> None:
    with atomic_h5(path, RUN_STAGE, config) as f:
        f.attrs.update({SOURCE_MESH: source_mesh, "worlds": run.worlds, "device": run.device})
        f.create_dataset(ANGLES, data=run.angles.astype(np.float64))
        f.create_dataset(SKIN, data=run.skin.astype(np.float32), chunks=(1, *run.skin.shape[1:]))
        for name in (RESIDUAL, NEWTON, CG, CONVERGED, SOLVE_MS):
            f.create_dataset(name, data=getattr(run, name))
        f[ANGLES].attrs.update(meaning="the 18 joint angles per frame (radians), scenes.hand_skeleton order",
                               names=",".join(ANGLE_NAMES))
        f[SKIN].attrs["meaning"] = "the skin embedded in the FEM's tets per frame (F, S, 3), world frame, metres"
        f[RESIDUAL].attrs["meaning"] = ("per frame the largest force on a free node over mu h^2 at the end of its "
                                        "minimisation (sim.fem.settings); frame 0 is the rest state")
        f[SOLVE_MS].attrs["meaning"] = ("milliseconds of the frame's minimisation (attr worlds sequences stepped "
                                        "together: the batch's time over them), frame 0: none")


def read_hand_run(path: str | os.PathLike, n_skin: int, skin: bool = True) -> HandRun:
    """A fem.h5 of a skin of `n_skin` vertices; one error naming the file for anything that does not fit. With
    `skin` False its shape is checked and the skin itself left on disk (`HandRun.skin` None): what a stage that
    reads one run's skin at a time plans with."""
    with open_artifact(path) as f:
        angles = read(f, ANGLES, np.float64)
        shape = dataset(f, SKIN).shape
        n = len(angles)
        if angles.shape != (n, len(ANGLE_NAMES)) or shape != (n, n_skin, 3) or n < 2:
            raise PipelineError(f"{path}: '{ANGLES}' {angles.shape} and '{SKIN}' {shape} must be (F, "
                                f"{len(ANGLE_NAMES)}) and (F, {n_skin}, 3), F >= 2")
        per_frame = {name: read(f, name) for name in (RESIDUAL, NEWTON, CG, CONVERGED, SOLVE_MS)}
        if any(v.shape != (n,) for v in per_frame.values()):
            raise PipelineError(f"{path}: {', '.join(per_frame)} must each hold one value a frame ({n})")
        return HandRun(angles, read(f, SKIN, np.float32) if skin else None, per_frame[RESIDUAL], per_frame[NEWTON],
                       per_frame[CG], per_frame[CONVERGED], per_frame[SOLVE_MS], int(f.attrs.get("worlds", 1)),
                       str(f.attrs.get("device", "")))
