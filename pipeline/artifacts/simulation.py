"""sim_low.h5 and sim_high.h5, written by the `simulate` stage: one solver run, frame by frame, of any solver kind
(pipeline/solvers/): the positions of its output mesh, the mesh, timing, and per-frame measures only some solvers
make, such as the cloth's harmonic residual (docs/artifacts.md, section "sim_low.h5 / sim_high.h5")."""
from __future__ import annotations

import contextlib
import dataclasses
import os
from typing import Any, Iterator, Literal, Mapping

import h5py
import numpy as np

from pipeline.core.errors import PipelineError
from pipeline.core.h5 import DROPPED, SOURCE_MESH, atomic_h5, config_of, open_artifact, read, read_indices


@dataclasses.dataclass(frozen=True)
class RunMeasure:
    """A per-frame quantity a solver kind reports beside a run's positions: dataset `name` with its `meaning`
    attr, and the file attrs that go with it. Made by the functions below, one per measure, so that each dataset
    name is written here."""

    name: str
    values: np.ndarray             # (F,) float64
    meaning: str
    attrs: Mapping[str, Any]


def harmonic_residual(values: np.ndarray, n_harmonics: int) -> RunMeasure:
    """The cloth's high-res run: how far each frame is from its harmonic constraint, with the number of modes."""
    return RunMeasure("harmonic_residual", np.asarray(values, dtype=np.float64),
                      "|B^T M x_high - t| / |B^T M x_high| per frame, t = B^T M S x_low (S x_low moved clear of the "
                      "body where it collides)", {"n_harmonics": n_harmonics})


@dataclasses.dataclass(frozen=True)
class SimulationRun:
    """What one run of a solver produced."""

    positions: np.ndarray          # (F, V, 3) float32 of the output mesh, frame 0 = the initial state
    faces: np.ndarray              # (T, 3)
    rest_vertices: np.ndarray      # (V, 3) float64
    pin_ids: np.ndarray            # (P,) vertices the solver moves kinematically (the cloth's pins)
    solve_ms: np.ndarray           # (F,) wall time of each frame's solve (frame 0: 0)
    n_constraints: int             # the solver's constraint count (the cloth's distance constraints)
    measures: tuple[RunMeasure, ...] = ()         # the solver kind's per-frame measures of this run
    dropped: str = ""                             # why the run is unusable though complete (a tangled cloth):
                                                  # kept for inspection, passed over by the dataset stage
    batch_worlds: int = 1                         # sequences stepped together (solve_ms is the whole batch's)
    setup_seconds: float = 0.0                    # the batch's work before its first step (reading, targets,
                                                  # the solver's construction)


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """The positions of a run, as the later stages read them."""

    positions: np.ndarray          # (F, V, 3) float64
    faces: np.ndarray              # (T, 3) int64


class SimulationWriter:
    """One run's file while the run is made: its frames written as they are stepped (`frames`, from any thread:
    h5py serialises its calls), the rest once the run is done (`finish`). Opened by `simulation_writer`."""

    def __init__(self, f: h5py.File, level: Literal["low", "high", "free"], device: str, n_frames: int):
        self._f, self._level, self._device = f, level, device
        self._written = np.zeros(n_frames, dtype=bool)
        self.finished = False

    def frames(self, first: int, positions: np.ndarray) -> None:
        """Frames first .. first + len(positions) - 1, (n, V, 3)."""
        self._f["positions"][first:first + len(positions)] = np.asarray(positions, dtype=np.float32)
        self._written[first:first + len(positions)] = True

    def finish(self, run: SimulationRun) -> None:
        """Everything but the positions, which `frames` has written, all of them."""
        if not self._written.all() or len(run.positions) != len(self._written):
            raise ValueError(f"{self._f.filename}: finished with frames {np.flatnonzero(~self._written)} not written")
        f, level = self._f, self._level
        f.create_dataset("faces", data=run.faces.astype(np.int32))
        f.create_dataset("rest_vertices", data=run.rest_vertices.astype(np.float64))
        f.create_dataset("pins/ids", data=run.pin_ids.astype(np.int64))
        f.create_dataset("solve_ms", data=run.solve_ms.astype(np.float64))
        f["solve_ms"].attrs["meaning"] = ("wall time of each frame's solve in ms, for the whole batch of `batch` "
                                          "sequences stepped together (frame 0: initial state, 0)")
        f.attrs.update(n_constraints=run.n_constraints, level=level, device=self._device, frames=len(run.positions),
                       batch=run.batch_worlds, setup_seconds=run.setup_seconds)
        for measure in run.measures:
            f.create_dataset(measure.name, data=measure.values.astype(np.float64))
            f[measure.name].attrs["meaning"] = measure.meaning
            f.attrs.update(measure.attrs)
        if run.dropped:
            f.attrs[DROPPED] = run.dropped
        self.finished = True


@contextlib.contextmanager
def simulation_writer(path: str | os.PathLike, level: Literal["low", "high", "free"], settings: Mapping[str, Any],
                      frames_vertices: tuple[int, int], device: str, source_mesh: str) -> Iterator[SimulationWriter]:
    """A writer of one run of (frames, vertices) positions; `settings` (the resolved scene settings) are its
    provenance `config`, `source_mesh` the `mesh_fingerprint` of the scene's low-res rest mesh (that of a
    high-res run too: the mesh it derives from). The file appears at `path` only if the block ends without error
    and the writer was finished."""
    with atomic_h5(path, f"simulate_{level}", settings) as f:
        f.attrs[SOURCE_MESH] = source_mesh
        f.create_dataset("positions", shape=(*frames_vertices, 3), dtype=np.float32)
        writer = SimulationWriter(f, level, device, frames_vertices[0])
        yield writer
        if not writer.finished:
            raise ValueError(f"{path}: the run's writer was left unfinished")


def write_simulation(path: str | os.PathLike, level: Literal["low", "high", "free"], settings: Mapping[str, Any],
                     run: SimulationRun, device: str, source_mesh: str) -> None:
    """Write one run made before (simulation_writer's arguments)."""
    with simulation_writer(path, level, settings, run.positions.shape[:2], device, source_mesh) as writer:
        writer.frames(0, run.positions)
        writer.finish(run)


def read_trajectory(path: str | os.PathLike) -> Trajectory:
    """Positions (F, V, 3) and faces, whose indices are checked against V."""
    with open_artifact(path) as f:
        n_vertices = _positions_shape(f)[1]
        return Trajectory(read(f, "positions", np.float64), read_indices(f, "faces", n_vertices, shape=(None, 3)))


def read_last_frame(path: str | os.PathLike) -> np.ndarray:
    """A run's last frame (V, 3) float64, without reading the others (a settle run's, where windows start)."""
    with open_artifact(path) as f:
        n_frames = _positions_shape(f)[0]
        return f["positions"][n_frames - 1].astype(np.float64)


def read_run_outline(path: str | os.PathLike) -> tuple[int, np.ndarray]:
    """The number of frames of a run and its faces (T, 3) int64, without reading its positions."""
    with open_artifact(path) as f:
        n_frames, n_vertices = _positions_shape(f)
        return n_frames, read_indices(f, "faces", n_vertices, shape=(None, 3))


def _positions_shape(f: h5py.File) -> tuple[int, int]:
    """Frames and vertices of a run's `positions` (F, V, 3)."""
    if "positions" not in f or f["positions"].ndim != 3 or f["positions"].shape[2] != 3:
        raise PipelineError(f"{f.filename}: missing dataset 'positions' (F, V, 3)")
    return f["positions"].shape[:2]


@dataclasses.dataclass(frozen=True)
class RunPhysics:
    """The time step and gravity a run was made with (its provenance config's `solver`)."""

    dt: float                      # seconds between stored frames
    gravity: np.ndarray            # (3,) scene units / s^2, world frame


def read_run_physics(path: str | os.PathLike) -> RunPhysics:
    """`solver.dt` and `solver.gravity` of the settings a run was made with, checked: dt finite and > 0, gravity
    three finite numbers, not all zero (its direction is a network input)."""
    with open_artifact(path) as f:
        solver = config_of(f).get("solver")
    if not isinstance(solver, dict) or "dt" not in solver or "gravity" not in solver:
        raise PipelineError(f"{path}: its config attr holds no solver.dt and solver.gravity: not a run written by "
                            f"pipeline.simulate")
    try:
        dt, gravity = float(solver["dt"]), np.asarray(solver["gravity"], dtype=np.float64)
    except (TypeError, ValueError):
        raise PipelineError(f"{path}: config solver.dt must be a number and solver.gravity three numbers") from None
    if not (np.isfinite(dt) and dt > 0) or gravity.shape != (3,) or not np.all(np.isfinite(gravity)) \
            or not np.any(gravity):
        raise PipelineError(f"{path}: config solver.dt must be finite and > 0 and solver.gravity three finite "
                            f"numbers, not all zero")
    return RunPhysics(dt, gravity)


def read_solve_ms(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """A run's ms per frame of its solve (frames 1.., frame 0 being the initial state) and the sequences its batch
    stepped together (whose total those ms are)."""
    with open_artifact(path) as f:
        solve_ms = read(f, "solve_ms", np.float64)
        batch = int(f.attrs.get("batch", 1))
    if solve_ms.ndim != 1 or len(solve_ms) < 2 or batch < 1 or not np.all(np.isfinite(solve_ms)):
        raise PipelineError(f"{path}: 'solve_ms' must hold finite ms of at least one solved frame (batch >= 1)")
    return solve_ms[1:], batch
