"""Mesh sequences and comparison scenes as files any viewer opens (OBJ per frame, binary glTF), via trimesh."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import trimesh


def write_obj_sequence(directory: str | Path, positions: np.ndarray, faces: np.ndarray,
                       frame_ids: Sequence[int]) -> list[Path]:
    """One `frame_NNNN.obj` per frame of positions (F, V, 3), vertex order and faces kept as given (a viewer's
    sequence importer plays them as an animation)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for frame, vertices in zip(frame_ids, positions):
        path = directory / f"frame_{int(frame):04d}.obj"
        trimesh.Trimesh(vertices, faces, process=False).export(path, file_type="obj", include_normals=False)
        paths.append(path)
    return paths


def write_glb(path: str | Path, meshes: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray | None]],
              gap: float = 0.15) -> Path:
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scene.export(path, file_type="glb")
    return path
