"""subdiv.h5, written by the `subdivide` stage: the Loop subdivision matrix S (high-res = S @ low-res), the
subdivided rest mesh and its harmonic basis (docs/artifacts.md, section "subdiv.h5")."""
from __future__ import annotations

import dataclasses
import os
from typing import Any, Mapping

import numpy as np
import scipy.sparse as sp

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, open_artifact, read, read_csr, read_indices, write_csr

STAGE = "subdivide"


@dataclasses.dataclass(frozen=True)
class Subdivision:
    """The high-res mesh as Loop subdivision of the low-res one."""

    S: sp.csr_matrix           # (V_high, V_low); every row sums to one
    vertices: np.ndarray       # (V_high, 3) float64 subdivided rest positions
    faces: np.ndarray          # (F_high, 3) int64


@dataclasses.dataclass(frozen=True)
class Harmonics:
    """The K lowest eigenvectors of the cotangent Laplacian, orthonormal under the lumped mass."""

    basis: np.ndarray          # (V_high, K) float64, B
    eigenvalues: np.ndarray    # (K,) float64, ascending
    mass: np.ndarray           # (V_high,) float64, diagonal of the barycentric lumped mass M


def write_subdiv(path: str | os.PathLike, config: Mapping[str, Any], levels: int, vertices_per_harmonic: int,
                 n_low_vertices: int, subdivision: Subdivision, harmonics: Harmonics, source_mesh: str) -> None:
    """Write the subdivision of a low-res mesh whose `mesh_fingerprint` is `source_mesh`."""
    with atomic_h5(path, STAGE, config) as f:
        f.attrs[SOURCE_MESH] = source_mesh
        f.attrs["levels"] = levels
        f.attrs["n_low_vertices"] = n_low_vertices
        f.attrs["n_high_vertices"] = len(subdivision.vertices)
        f.attrs["n_harmonics"] = harmonics.basis.shape[1]
        f.attrs["vertices_per_harmonic"] = vertices_per_harmonic
        write_csr(f, "S", subdivision.S)
        f.create_dataset("vertices", data=subdivision.vertices.astype(np.float64))
        f.create_dataset("faces", data=subdivision.faces.astype(np.int32))
        group = f.create_group("harmonics")
        group.attrs["laplacian"] = "cotangent"
        group.attrs["mass"] = "barycentric lumped"
        group.create_dataset("basis", data=harmonics.basis)
        group.create_dataset("eigenvalues", data=harmonics.eigenvalues)
        group.create_dataset("mass", data=harmonics.mass)


def read_subdivision(path: str | os.PathLike) -> Subdivision:
    with open_artifact(path) as f:
        vertices = read(f, "vertices", np.float64)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise PipelineError(f"{path}: dataset 'vertices' has shape {vertices.shape}, expected (any, 3)")
        faces = read_indices(f, "faces", len(vertices), shape=(None, 3))
        S = read_csr(f, "S")
    if S.shape[0] != len(vertices):
        raise PipelineError(f"{path}: S has {S.shape[0]} rows but the subdivided mesh has {len(vertices)} vertices")
    return Subdivision(S, vertices, faces)


def read_vertex_counts(path: str | os.PathLike) -> tuple[int, int]:
    """(low-res, high-res) vertex counts from the attributes alone: what a frame of the runs and the dataset
    weighs (pipeline.workflow_plan), without reading the matrices."""
    with open_artifact(path) as f:
        counts = [f.attrs.get(name) for name in ("n_low_vertices", "n_high_vertices")]
    if not all(isinstance(n, (int, np.integer)) and 0 < n < 2 ** 31 for n in counts):
        raise PipelineError(f"{path}: attributes n_low_vertices and n_high_vertices must be positive integers")
    return int(counts[0]), int(counts[1])


def read_harmonics(path: str | os.PathLike) -> Harmonics:
    with open_artifact(path) as f:
        return Harmonics(read(f, "harmonics/basis", np.float64), read(f, "harmonics/eigenvalues", np.float64),
                         read(f, "harmonics/mass", np.float64))
