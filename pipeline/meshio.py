"""Loading user meshes (OBJ/PLY through trimesh, or the pipeline's own HDF5 artifacts) with validation."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pipeline.artifacts.h5 import open_artifact
from pipeline.errors import PipelineError
from geometry.mesh import validate_mesh

# Where each artifact kind keeps its mesh: the first group path found in a file wins.
_H5_MESH_GROUPS = ("", "rest", "levels/0")


def load_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and faces (F, 3) int64 of a mesh file, validated.

    Accepts .obj/.ply/.off/.stl (read with trimesh without merging or reordering vertices) and .h5 artifacts
    holding `vertices` and `faces` at the root, under `rest/`, or under `levels/0/`.
    """
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: input file does not exist")
    if path.suffix.lower() in (".h5", ".hdf5"):
        vertices, faces = _load_h5_mesh(path)
    else:
        vertices, faces = _load_trimesh(path)
    check_mesh(path, vertices, faces)
    return vertices, faces


def check_mesh(source: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Validate a mesh, turning the geometric complaint into an error that names its source."""
    try:
        validate_mesh(vertices, faces)
    except ValueError as err:
        raise PipelineError(f"{source}: {err}") from None


def _load_h5_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with open_artifact(path) as f:
        for group in _H5_MESH_GROUPS:
            prefix = f"{group}/" if group else ""
            if f"{prefix}vertices" in f and f"{prefix}faces" in f:
                # NaN is a validation matter here, reported per vertex by check_mesh.
                return np.asarray(f[f"{prefix}vertices"][()], dtype=np.float64), \
                    np.asarray(f[f"{prefix}faces"][()], dtype=np.int64)
    raise PipelineError(f"{path}: no mesh found (expected 'vertices' and 'faces' at the root, 'rest/' or 'levels/0/')")


def _load_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh  # imported here: only mesh files need it, and it is slow to import

    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as err:  # trimesh raises many types for unreadable files
        raise PipelineError(f"{path}: cannot read mesh ({type(err).__name__}: {err})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise PipelineError(f"{path}: file holds no triangle mesh")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)

