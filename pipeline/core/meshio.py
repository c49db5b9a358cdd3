"""Loading user meshes (OBJ/PLY/OFF/STL, or the pipeline's own HDF5 artifacts) with validation.

A mesh's vertices keep the order and count of the file: Loop subdivision's S, pins and every artifact index
vertices by their position, so a loader that dropped or renumbered a vertex would silently misalign them.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from geometry.mesh import validate_mesh
from pipeline.core.errors import PipelineError
from pipeline.core.h5 import FLOAT32_MAX, open_artifact, read_indices, require_input_file

# Where each artifact kind keeps its mesh: the first group path found in a file wins.
_H5_MESH_GROUPS = ("", "rest", "levels/0")


def load_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and faces (F, 3) int64 of a mesh file, validated.

    Accepts .obj (read here, vertices in file order), .ply/.off/.stl (read with trimesh without merging or
    reordering vertices) and .h5 artifacts holding `vertices` and `faces` at the root, under `rest/`, or under
    `levels/0/`. A vertex that no face uses is refused by the validation, not dropped.
    """
    vertices, faces, _ = load_mesh_groups(path)
    check_mesh(path, vertices, faces)
    return vertices, faces


def load_mesh_groups(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Vertices, faces and named vertex groups of a mesh file, not yet validated (a garment's panels are checked
    once welded). The groups are an OBJ's `g` and `o` groups: each name maps to the vertices of the faces listed
    under it (a name used twice gathers both); other formats have none."""
    path = Path(path)
    require_input_file(path)
    if path.suffix.lower() in (".h5", ".hdf5"):
        return (*_load_h5_mesh(path), {})
    if path.suffix.lower() == ".obj":
        return _load_obj(path)
    return (*_load_trimesh(path), {})


def check_mesh(source: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Validate a mesh, turning the geometric complaint into an error that names its source. Coordinates must
    also fit float32, in which the solver and the network compute (1e39 is finite in float64, inf there)."""
    try:
        validate_mesh(vertices, faces)
    except ValueError as err:
        raise PipelineError(f"{source}: {err}") from None
    beyond = np.flatnonzero(np.abs(vertices).max(axis=1) > FLOAT32_MAX)
    if len(beyond):
        raise PipelineError(f"{source}: vertex {beyond[0]} at {vertices[beyond[0]].tolist()} lies beyond float32's "
                            f"range (at most {FLOAT32_MAX:.3g} per coordinate)")


def _load_h5_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with open_artifact(path) as f:
        for group in _H5_MESH_GROUPS:
            prefix = f"{group}/" if group else ""
            if f"{prefix}vertices" in f and f"{prefix}faces" in f:
                # NaN is a validation matter here, reported per vertex by check_mesh.
                vertices = np.asarray(f[f"{prefix}vertices"][()], dtype=np.float64)
                return vertices, read_indices(f, f"{prefix}faces", len(vertices), shape=(None, 3))
    raise PipelineError(f"{path}: no mesh found (expected 'vertices' and 'faces' at the root, 'rest/' or 'levels/0/')")


def _load_obj(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Positions, faces and `g`/`o` groups of an OBJ file, vertex i being the file's i-th `v` line.

    Read here, not with trimesh: trimesh drops vertices that no face uses and splits vertices along texture
    seams, renumbering the rest. Polygons are fanned into triangles; indices may be negative (relative to the
    vertices read so far); texture coordinates, normals, materials, lines and points are ignored.
    """
    vertices, faces, face_group, names = [], [], [], {}
    group = -1
    text = path.read_text(encoding="utf-8", errors="replace").replace("\\\n", " ")   # joined continuation lines
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        try:
            if fields[:1] == ["v"]:
                if len(fields) < 4:
                    raise ValueError("a vertex needs three coordinates")
                vertices.append([float(x) for x in fields[1:4]])
            elif fields[:1] == ["f"]:
                ids = [int(token.split("/", 1)[0]) for token in fields[1:]]
                if len(ids) < 3 or 0 in ids:
                    raise ValueError("a face needs three or more vertex indices, counted from 1")
                ids = [i - 1 if i > 0 else len(vertices) + i for i in ids]
                faces.extend((ids[0], ids[k], ids[k + 1]) for k in range(1, len(ids) - 1))
                face_group.extend([group] * (len(ids) - 2))
            elif fields[:1] in (["g"], ["o"]) and len(fields) > 1:
                group = names.setdefault(" ".join(fields[1:]), len(names))
        except ValueError as err:
            # Named by its number, never quoted: int() and float() would quote the line's words too.
            raise PipelineError(f"{path}: line {number}: a 'v' line needs three numbers, an 'f' line three or "
                                f"more vertex indices counted from 1") from None
    if not faces:
        raise PipelineError(f"{path}: file holds no triangle mesh")
    faces, face_group = np.asarray(faces, dtype=np.int64), np.asarray(face_group, dtype=np.int64)
    groups = {name: np.unique(faces[face_group == index]) for name, index in names.items()}
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 3), faces, groups


def _load_trimesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh  # imported here: only mesh files need it, and it is slow to import

    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as err:  # trimesh raises many types for unreadable files
        raise PipelineError(f"{path}: cannot read mesh ({type(err).__name__}: {err})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise PipelineError(f"{path}: file holds no triangle mesh")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)

