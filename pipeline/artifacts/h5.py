"""Reading and writing the HDF5 artifacts that stages exchange.

Every artifact is written to a temporary file next to its final path and renamed only once complete, so an
interrupted or failed stage never leaves a half-written file that Snakemake would take for a finished one.
Every artifact carries the same provenance attrs: `stage`, `config` (JSON of the settings that made it),
`versions` (JSON of package versions) and `length_unit`.
"""
from __future__ import annotations

import contextlib
import importlib.metadata
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator, Mapping

import h5py
import numpy as np
import scipy.sparse as sp

from pipeline.errors import PipelineError

_VERSIONED_PACKAGES = ("numpy", "scipy", "h5py", "warp-lang", "trimesh", "lap", "torch", "snakemake")


def package_versions() -> dict[str, str]:
    """Versions of the packages that can influence an artifact's contents ('absent' if not installed)."""
    versions = {}
    for name in _VERSIONED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "absent"
    return versions


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, stage: str, config: Mapping[str, Any] | None = None) -> Iterator[h5py.File]:
    """Open a new HDF5 file for writing that appears at `path` only if the block finishes without error.

    Provenance attrs are set up front; the caller adds datasets and stage-specific attrs.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp.h5", dir=path.parent)
    os.close(fd)
    try:
        with h5py.File(tmp_name, "w") as f:
            f.attrs["stage"] = stage
            f.attrs["config"] = json.dumps(config or {}, sort_keys=True, default=_json_default)
            f.attrs["versions"] = json.dumps(package_versions(), sort_keys=True)
            f.attrs["length_unit"] = "scene unit (~1 m), y up"
            yield f
        os.replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp_name)
        raise


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot record {type(obj).__name__} in an artifact's config attr")


def open_artifact(path: str | os.PathLike) -> h5py.File:
    """Open an existing artifact read-only, with a clear error if it is missing or not HDF5."""
    path = Path(path)
    if not path.is_file():
        raise PipelineError(f"{path}: input file does not exist")
    try:
        return h5py.File(path, "r")
    except OSError as err:
        raise PipelineError(f"{path}: not a readable HDF5 file ({err})") from None


def read(f: h5py.File, name: str, dtype: Any = None) -> np.ndarray:
    """Read a whole dataset, naming the file and dataset if it is absent or holds NaN/inf."""
    if name not in f:
        raise PipelineError(f"{f.filename}: missing dataset '{name}'")
    data = f[name][()]
    if dtype is not None:
        data = np.asarray(data, dtype=dtype)
    if np.issubdtype(np.asarray(data).dtype, np.floating) and not np.all(np.isfinite(data)):
        raise PipelineError(f"{f.filename}: dataset '{name}' contains NaN or inf")
    return data


def config_of(f: h5py.File) -> dict[str, Any]:
    """The config recorded in an artifact's attrs."""
    return json.loads(f.attrs.get("config", "{}"))


def write_csr(group: h5py.Group, name: str, matrix: sp.spmatrix) -> None:
    """Store a sparse matrix as CSR datasets `name/data`, `name/indices`, `name/indptr`, `name/shape`."""
    csr = sp.csr_matrix(matrix)
    csr.sort_indices()
    g = group.create_group(name)
    g.create_dataset("data", data=csr.data.astype(np.float64))
    g.create_dataset("indices", data=csr.indices.astype(np.int64))
    g.create_dataset("indptr", data=csr.indptr.astype(np.int64))
    g.create_dataset("shape", data=np.asarray(csr.shape, dtype=np.int64))


def read_csr(f: h5py.File, name: str) -> sp.csr_matrix:
    """Load a matrix stored by `write_csr`."""
    parts = [read(f, f"{name}/{p}") for p in ("data", "indices", "indptr", "shape")]
    data, indices, indptr, shape = parts
    try:
        return sp.csr_matrix((data, indices, indptr), shape=tuple(int(s) for s in shape))
    except ValueError as err:
        raise PipelineError(f"{f.filename}: sparse matrix '{name}' is malformed ({err})") from None
