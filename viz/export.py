"""Meshes and comparison scenes as the bytes of files any viewer opens (OBJ, binary glTF), via trimesh; the
caller writes them (a stage: pipeline.core.h5.write_bytes, so a full disk is one error naming the file)."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import trimesh


def obj_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """One mesh as OBJ, vertex order and faces kept as given (a viewer's sequence importer plays files of
    `frame_NNNN.obj` as an animation)."""
    return trimesh.Trimesh(vertices, faces, process=False).export(file_type="obj", include_normals=False).encode()


def glb_bytes(meshes: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray | None]], gap: float = 0.15) -> bytes:
    """One binary glTF holding named meshes (name, vertices, faces, RGBA vertex colours or None), laid side by
    side along x with `gap` (relative to the widest mesh) between them."""
    scene = trimesh.Scene()
    width = max(float(np.ptp(v[:, 0])) for _, v, _, _ in meshes)
    offset = 0.0
    for name, vertices, faces, colors in meshes:
        shift = np.array([offset - vertices[:, 0].min(), 0.0, 0.0])
        mesh = trimesh.Trimesh(vertices + shift, faces, process=False)
        if colors is not None:
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=(np.asarray(colors) * 255).astype(np.uint8))
        scene.add_geometry(mesh, node_name=name, geom_name=name)
        offset += float(np.ptp(vertices[:, 0])) + gap * width
    return scene.export(file_type="glb")
