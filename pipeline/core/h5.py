"""Reading and writing the HDF5 artifacts that stages exchange, and the one way any stage writes a file.

Every output (HDF5 or not) is written to a fresh, uniquely named temporary file next to its final path and
renamed only once complete, so an interrupted or failed stage never leaves a half-written file that Snakemake
would take for a finished one, and a link planted at a predictable name cannot redirect the write.
Every artifact carries the same provenance attrs: `stage`, `config` (JSON of the settings that made it),
`versions` (JSON of package versions) and `length_unit`. Every artifact derived from a scene's low-res rest mesh
also carries `source_mesh`, that mesh's `mesh_fingerprint`, so that a stage can refuse inputs made from different
meshes (`check_same_mesh`) even where their vertex counts agree.

Reads trust nothing in the file: `read` refuses NaN/inf and values beyond float32's range, `read_indices` index
arrays out of range or of the wrong shape, `read_csr` malformed sparse matrices, each as one `PipelineError`
naming the file and dataset (an out-of-range index would otherwise reach scipy's or Warp's unchecked loops: a
segfault, not an error); whatever else a damaged file makes h5py raise inside `open_artifact` becomes one such
error too. A write that the file system refuses (a read-only folder, an output path that is a folder, a full
disk) is one error naming the output, whichever library wrote (`_TempFile`).
"""
from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import functools
import hashlib
import importlib.metadata
import json
import os
import re
import stat
import tempfile
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Mapping

import h5py
import numpy as np
import scipy.sparse as sp

from pipeline.core.errors import PipelineError
from pipeline.core.h5_indirection import refuse_indirection

_VERSIONED_PACKAGES = ("numpy", "scipy", "h5py", "warp-lang", "trimesh", "lap", "torch", "snakemake")


@functools.cache
def package_versions() -> dict[str, str]:
    """Versions of the packages that can influence an artifact's contents ('absent' if not installed). Looked up
    once a process (~40 ms: a batch job writing 64 runs spent 2.6 s here); the caller must not change the dict."""
    versions = {}
    for name in _VERSIONED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "absent"
    return versions


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~_current_umask()     # what open() would give a new file; mkstemp makes it 0600


@contextlib.contextmanager
def _replaced_on_success(path: str | os.PathLike, suffix: str, keep_going: bool) -> Iterator[_TempFile]:
    """A new, empty temporary file beside `path` that replaces `path` once the block finishes, and is removed
    if it fails; a write the file system refused is one error naming `path`, whatever the writer (torch, h5py)
    made of it (`_TempFile`, `keep_going`).

    mkstemp picks an unused name and creates it exclusively (O_EXCL), so neither a link planted beside the
    output nor a second run writing the same output at the same time can be written through; `os.replace`
    renames within one directory, so readers see the old file or the whole new one, and a link at `path`
    itself is replaced, not followed. Temporary files of this output left by a killed run go first
    (`_sweep_stale`): each is as large as the partial output.
    """
    path = Path(path)
    with _output_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        _sweep_stale(path, suffix)
        out = _TempFile(*_locked_temp(path, suffix), keep_going)
    try:
        try:
            yield out
        except BaseException:
            if out.error is None:
                raise
        with _output_errors(path):
            if out.error is not None:
                raise out.error
            os.replace(out.name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(out.name)
        raise
    finally:
        os.close(out.fd)


def _temp_names(path: Path, suffix: str) -> re.Pattern:
    """The names tempfile.mkstemp gives this output's temporary files (8 characters of its alphabet)."""
    return re.compile(re.escape(f".{path.name}.") + r"[a-z0-9_]{8}" + re.escape(suffix))


def _locked_temp(path: Path, suffix: str) -> tuple[int, str]:
    """A new temporary file for `path`, locked (flock) for as long as its descriptor is open, so that
    `_sweep_stale` of a run writing the same output tells it from one a killed run left: the kernel drops a
    dead process's locks. One swept between its creation and its lock is made anew."""
    while True:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
        fcntl.flock(fd, fcntl.LOCK_EX)
        if os.fstat(fd).st_nlink > 0:
            os.fchmod(fd, _FILE_MODE)
            return fd, name
        os.close(fd)


def _sweep_stale(path: Path, suffix: str) -> None:
    """Remove the temporary files of `path` (its own names only: `_temp_names`) that no live writer holds."""
    names = _temp_names(path, suffix)
    for entry in os.scandir(path.parent):
        if not names.fullmatch(entry.name):
            continue
        try:      # O_NOFOLLOW, O_NONBLOCK and the regular-file check: a planted link or FIFO is left alone
            fd = os.open(entry.path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError:
            continue
        try:
            if stat.S_ISREG(os.fstat(fd).st_mode) and _unlocked(fd):
                os.remove(entry.path)
        finally:
            os.close(fd)


def _unlocked(fd: int) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


class _TempFile:
    """An output's temporary file as a binary file object (positioned reads and writes on its descriptor) that
    remembers the first write the file system refused (a full disk, a file size limit, a read-only or
    vanished medium).

    Writers turn that refusal into their own errors (torch: `RuntimeError ... unexpected pos`), so the output
    layer reports the remembered one. With `keep_going` (HDF5, through h5py's file-object driver) the refused
    write and every later one are dropped and reported done: libhdf5 fails to clean up after a failed write
    (closing the file after one leaves dataset ids over freed memory: a segfault at exit), so it must never
    see one; the block runs to its end and the remembered error replaces its output.
    """

    def __init__(self, fd: int, name: str, keep_going: bool):
        self.fd, self.name, self.keep_going = fd, name, keep_going
        self.error: OSError | None = None
        self._position = 0
        self._end = 0          # the end of the file, writes dropped after an error included

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        if self.error is None:
            try:
                done = 0
                while done < len(view):
                    done += os.pwrite(self.fd, view[done:], self._position + done)
            except OSError as err:
                self.error = err
                if not self.keep_going:
                    raise
        self._position += len(view)
        self._end = max(self._end, self._position)
        return len(view)

    def read(self, size: int) -> bytes:
        buffer = bytearray(size)
        return bytes(buffer[:self.readinto(buffer)])

    def readinto(self, buffer) -> int:
        view = memoryview(buffer).cast("B")
        count = os.preadv(self.fd, [view], self._position)
        self._position += count
        return count

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._position, os.SEEK_END: self._end}[whence]
        self._position = base + offset
        return self._position

    def tell(self) -> int:
        return self._position

    def truncate(self, size: int | None = None) -> int:
        size = self._position if size is None else size
        if self.error is None:
            try:
                os.ftruncate(self.fd, size)
            except OSError as err:
                self.error = err
                if not self.keep_going:
                    raise
        self._end = size
        return size

    def flush(self) -> None:
        """Writes go straight to the descriptor: nothing to flush."""

    def readable(self) -> bool:
        return True

    writable = seekable = readable


@contextlib.contextmanager
def _output_errors(path: str | os.PathLike) -> Iterator[None]:
    """The file system's refusal to create, fill or rename an output (a read-only folder, a folder or a regular
    file where the output or its folder should be, a full disk) as one error naming the output."""
    try:
        yield
    except OSError as err:
        path = Path(path)
        raise PipelineError(f"{path}: cannot write the output ({_why_unwritable(path, err)})") from None


def _why_unwritable(path: Path, err: OSError) -> str:
    if path.is_dir():
        return "it is a folder"
    blocking = next((parent for parent in path.parents if parent.exists() and not parent.is_dir()), None)
    if blocking is not None:
        return f"{blocking} is a file, not a folder"
    return err.strerror or str(err)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file to write that appears at `path` only if the block finishes without error (every output
    that is not HDF5: model.pt, the training checkpoint, report.md, renders, videos)."""
    with _replaced_on_success(path, ".tmp", keep_going=False) as out:
        yield out


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """`data` as the file `path`, through `atomic_write`."""
    with atomic_write(path) as f:
        f.write(data)


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, stage: str, config: Mapping[str, Any] | None = None) -> Iterator[h5py.File]:
    """Open a new HDF5 file for writing that appears at `path` only if the block finishes without error.

    Provenance attrs are set up front; the caller adds datasets and stage-specific attrs. libhdf5 writes
    through h5py's file-object driver into a `_TempFile` that never tells it of a refused write (see there).
    """
    with _replaced_on_success(path, ".tmp.h5", keep_going=True) as out:
        with h5py.File(out, "w") as f:
            f.attrs["stage"] = stage
            f.attrs["config"] = json.dumps(config or {}, sort_keys=True, default=_json_default)
            f.attrs["versions"] = json.dumps(package_versions(), sort_keys=True)
            f.attrs["length_unit"] = "scene unit (~1 m), y up"
            yield f


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot record {type(obj).__name__} in an artifact's config attr")


def require_input_file(path: Path) -> None:
    """Refuse an input path that is no regular file, saying what it is: a folder, a FIFO or a device such as
    /dev/zero was once reported as "does not exist" (and a FIFO, opened, would block the stage)."""
    if path.is_file():
        return
    if not path.exists():
        raise PipelineError(f"{path}: input file does not exist")
    kind = "a folder" if path.is_dir() else "a FIFO" if path.is_fifo() else "a device" if (
        path.is_block_device() or path.is_char_device()) else "a socket"
    raise PipelineError(f"{path}: input is {kind}, not a regular file")


@contextlib.contextmanager
def open_artifact(path: str | os.PathLike) -> Iterator[h5py.File]:
    """An existing artifact opened read-only for the block, with one clear error if it is missing or not HDF5,
    or if reading it fails in the block.

    Damaged metadata (a header, a B-tree or a heap overwritten) makes h5py raise what libhdf5 reports, as
    OSError, KeyError, RuntimeError or ValueError, and the reader's conversions of what it got may raise more:
    inside the block all of it is about this file's contents, so all of it becomes one `PipelineError` naming
    the file (the reader's own `PipelineError`s pass unchanged). A file that takes data from other files
    (external links, virtual datasets, external storage) is refused before the block reads anything.
    """
    path = Path(path)
    require_input_file(path)
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise PipelineError(f"{path}: not a readable HDF5 file ({_one_line(err)})") from None
    with f:
        try:
            refuse_indirection(f)
            yield f
        except PipelineError:
            raise
        except Exception as err:     # h5py and numpy raise many types for a damaged file; see the docstring
            raise PipelineError(f"{path}: damaged or unreadable HDF5 file ({type(err).__name__}: "
                                f"{_one_line(err)})") from None


def _one_line(err: Exception) -> str:
    """An exception's message on one line (a KeyError's without the quotes its str() adds)."""
    return " ".join(str(err.args[0] if len(err.args) == 1 else err).split())


# Every floating-point array ends up in float32 (Warp's kernels, torch's network, the artifacts' positions): a
# finite float64 beyond this would turn into inf there.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def dataset(f: h5py.File, name: str) -> h5py.Dataset:
    """The dataset `name` unread (its shape, dtype, chunks); one error naming the file if it is absent or a group."""
    if name not in f:
        raise PipelineError(f"{f.filename}: missing dataset '{name}'")
    if not isinstance(f[name], h5py.Dataset):
        raise PipelineError(f"{f.filename}: '{name}' is a group, not a dataset")
    return f[name]


def read(f: h5py.File, name: str, dtype: Any = None) -> np.ndarray:
    """Read a whole dataset, naming the file and dataset if it is absent or holds NaN, inf or a value beyond
    float32's range; with a `dtype`, it must hold real numbers (numpy would turn text into an error of its own
    and drop an imaginary part with a warning)."""
    dataset(f, name)
    if dtype is not None and f[name].dtype.kind not in "biuf":
        raise PipelineError(f"{f.filename}: dataset '{name}' holds {f[name].dtype} values, not real numbers")
    data = f[name][()]
    if np.issubdtype(np.asarray(data).dtype, np.floating):
        # checked before any conversion: float32 would turn a huge value into inf, with a warning on stderr
        with np.errstate(invalid="ignore"):
            if not np.all(np.abs(data) <= FLOAT32_MAX):
                raise PipelineError(f"{f.filename}: dataset '{name}' contains NaN, inf or values beyond float32's "
                                    f"range")
    if dtype is not None:
        data = np.asarray(data, dtype=dtype)
    return data


def read_strings(f: h5py.File, name: str) -> np.ndarray:
    """A 1-D dataset of byte strings (a table's text column) as str, naming the file and dataset otherwise."""
    column = f.get(name)
    if not isinstance(column, h5py.Dataset) or column.dtype.kind != "S" or column.ndim != 1:
        raise PipelineError(f"{f.filename}: missing dataset '{name}' (one string per row)")
    return np.array([value.decode() for value in column[()]], dtype=str)


def read_or_nan(f: h5py.File, name: str) -> np.ndarray:
    """A float dataset as `read` checks it, but NaN allowed: a table's column where NaN means "not measured" (a
    split the scene lacks); inf and values beyond float32's range are still refused."""
    column = f.get(name)
    if not isinstance(column, h5py.Dataset) or column.dtype.kind != "f":
        return read(f, name, np.float64)        # its error: missing, a group, or not real numbers
    data = np.asarray(column[()], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        if not np.all(np.isnan(data) | (np.abs(data) <= FLOAT32_MAX)):
            raise PipelineError(f"{f.filename}: dataset '{name}' contains inf or values beyond float32's range")
    return data


@dataclasses.dataclass(frozen=True)
class ColumnTable:
    """The columns of a one-row-per-run table artifact (tradeoff.h5, convs.h5) by type; floats in `nan_allowed`
    may hold NaN ("not measured")."""
    strings: tuple[str, ...]
    ints: tuple[str, ...]
    floats: tuple[str, ...]
    nan_allowed: tuple[str, ...] = ()

    def write(self, f: h5py.File, columns: Mapping[str, np.ndarray]) -> None:
        for name in self.strings:
            f.create_dataset(name, data=np.array(columns[name], dtype="S"))
        for name in self.ints:
            f.create_dataset(name, data=np.asarray(columns[name], dtype=np.int64))
        for name in self.floats:
            f.create_dataset(name, data=np.asarray(columns[name], dtype=np.float64))

    def read(self, f: h5py.File) -> dict[str, np.ndarray]:
        """Every column, checked, each with one value per row."""
        columns = {name: read_strings(f, name) for name in self.strings}
        columns.update({name: read(f, name, np.int64) for name in self.ints})
        columns.update({name: read_or_nan(f, name) if name in self.nan_allowed else read(f, name, np.float64)
                        for name in self.floats})
        n_rows = len(columns[self.strings[0]])
        if any(values.shape != (n_rows,) for values in columns.values()):
            raise PipelineError(f"{f.filename}: its columns do not all have one value per row ({n_rows})")
        return columns


def config_of(f: h5py.File) -> dict[str, Any]:
    """The config recorded in an artifact's attrs."""
    return json.loads(f.attrs.get("config", "{}"))


SOURCE_MESH = "source_mesh"      # root attr: mesh_fingerprint of the low-res rest mesh an artifact derives from


def mesh_fingerprint(vertices: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 (hex) of a mesh: its shapes, float64 vertices and int64 faces. Artifacts store vertices as float64
    and faces as int32 or int64, so a mesh read back from any of them has the fingerprint it was written with."""
    digest = hashlib.sha256()
    for array in (np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64)):
        digest.update(np.asarray(array.shape, dtype=np.int64).tobytes())
        digest.update(array.tobytes())
    return digest.hexdigest()


def check_same_mesh(path: str | os.PathLike, other: str | os.PathLike, other_fingerprint: str | None = None) -> None:
    """Refuse `path` unless it derives from the same low-res mesh as `other` (whose fingerprint is
    `other_fingerprint`, or else its `source_mesh` attr).

    Equal vertex counts are not enough: S of another mesh of as many vertices multiplies without complaint and
    gives a high-res run, or a dataset, of nonsense. An artifact without the attr (made by hand, as test fixtures
    are) is not checked: it can only be compared where both sides have a fingerprint.
    """
    fingerprint = source_mesh_of(path)
    other_fingerprint = other_fingerprint or source_mesh_of(other)
    if fingerprint is not None and other_fingerprint is not None and fingerprint != other_fingerprint:
        raise PipelineError(f"{path}: made from another mesh than {other}")


def source_mesh_of(path: str | os.PathLike) -> str | None:
    """The `source_mesh` attr of an artifact (None without one), for an artifact made from it to carry on."""
    with open_artifact(path) as f:
        value = f.attrs.get(SOURCE_MESH)
    return None if value is None else str(value)


DROPPED = "dropped"     # root attr of an artifact that stands for a sequence dropped on the way, with the reason


def write_dropped(path: str | os.PathLike, stage: str, config: Mapping[str, Any] | None, reason: str,
                  attrs: Mapping[str, Any]) -> None:
    """The artifact of a sequence that a stage dropped (a library window whose clip cannot be played, a run that
    tangled): no datasets, its `dropped` reason and `attrs` (which sequence, its source mesh), so that the rule's
    output exists, the stages after it pass the sequence over and say why, and the run goes on."""
    with atomic_h5(path, stage, config) as f:
        f.attrs.update(attrs)
        f.attrs[DROPPED] = reason


def dropped_reason(path: str | os.PathLike) -> str | None:
    """Why the sequence of the artifact at `path` was dropped (write_dropped), or None for an ordinary artifact."""
    with open_artifact(path) as f:
        value = f.attrs.get(DROPPED)
    return None if value is None else str(value)


def write_csr(group: h5py.Group, name: str, matrix: sp.spmatrix) -> None:
    """Store a sparse matrix as CSR datasets `name/data`, `name/indices`, `name/indptr`, `name/shape`."""
    csr = sp.csr_matrix(matrix)
    csr.sort_indices()
    g = group.create_group(name)
    g.create_dataset("data", data=csr.data.astype(np.float64))
    g.create_dataset("indices", data=csr.indices.astype(np.int64))
    g.create_dataset("indptr", data=csr.indptr.astype(np.int64))
    g.create_dataset("shape", data=np.asarray(csr.shape, dtype=np.int64))


def read_indices(f: h5py.File, name: str, upper: int, shape: tuple[int | None, ...] | None = None,
                 lower: int = 0) -> np.ndarray:
    """An integer index array as int64, refused unless every entry lies in [lower, upper) and its shape matches
    `shape` (None: any length along that axis)."""
    if name not in f:
        raise PipelineError(f"{f.filename}: missing dataset '{name}'")
    stored = f[name]
    if not isinstance(stored, h5py.Dataset) or not np.issubdtype(stored.dtype, np.integer):
        raise PipelineError(f"{f.filename}: '{name}' must be an integer dataset of indices")
    if shape is not None and (len(stored.shape) != len(shape)
                              or any(want is not None and got != want for got, want in zip(stored.shape, shape))):
        wanted = "(" + ", ".join("any" if n is None else str(n) for n in shape) + ")"
        raise PipelineError(f"{f.filename}: dataset '{name}' has shape {stored.shape}, expected {wanted}")
    data = np.asarray(stored[()], dtype=np.int64)
    if data.size and (data.min() < lower or data.max() >= upper):
        raise PipelineError(f"{f.filename}: dataset '{name}' holds indices outside [{lower}, {upper}) "
                            f"(found {data.min()}..{data.max()})")
    return data


def read_csr(f: h5py.File, name: str) -> sp.csr_matrix:
    """Load a matrix stored by `write_csr`, refusing any that scipy would index out of bounds with: a shape of
    two non-negative sizes, `indptr` of rows + 1 entries rising from 0 to nnz, `indices` in [0, columns)."""
    shape = read_indices(f, f"{name}/shape", np.iinfo(np.int32).max, shape=(2,))
    rows, columns = (int(n) for n in shape)
    data = read(f, f"{name}/data", np.float64)
    if data.ndim != 1:
        raise PipelineError(f"{f.filename}: dataset '{name}/data' has shape {data.shape}, expected (any,)")
    indptr = read_indices(f, f"{name}/indptr", len(data) + 1, shape=(rows + 1,))
    indices = read_indices(f, f"{name}/indices", columns, shape=(len(data),))
    if indptr[0] != 0 or indptr[-1] != len(data) or np.any(np.diff(indptr) < 0):
        raise PipelineError(f"{f.filename}: sparse matrix '{name}' is malformed (indptr must rise from 0 to the "
                            f"{len(data)} stored entries)")
    return sp.csr_matrix((data, indices, indptr), shape=(rows, columns))
