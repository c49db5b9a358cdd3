"""Made-up stage inputs that need no simulation: a small square sheet and runs of it waving, written as the
subdivide and simulate stages write them (for the learning-stage, multi-garment, hostile-input and export tests),
and a stage run in this process.

The sheet is not geometry.shapes.grid_patch: that numbers the same square's vertices from the other corner, and
these tests' expected numbers were written for this order.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from geometry.loop_subdivision import loop_subdivide
from pipeline.core import cli
from pipeline.core.h5 import SOURCE_MESH, atomic_h5, mesh_fingerprint, write_csr

N_FRAMES = 12              # the runs' frames, unless a caller asks for others
# The solver settings a run records (pipeline.simulate): the dataset reads its frame time and gravity there.
SIM_CONFIG = {"solver": {"dt": 0.1, "gravity": [0.0, -9.81, 0.0]}}


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A hanging n x n square in the xy plane, CCW faces seen from +z."""
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    vertices = np.stack([c.ravel() / (n - 1) - 0.5, 1.0 - r.ravel() / (n - 1), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, d, e = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return vertices, np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])


def write_waving_sheet(folder: Path, n: int = 5, *, levels: int = 2, n_frames: int = N_FRAMES,
                       runs_folder: str = "", transform: Callable[[np.ndarray, int], np.ndarray] = lambda x, f: x,
                       source_mesh: bool = False) -> None:
    """folder/subdiv.h5 (`levels` Loop subdivisions of grid(n)) and, in folder/runs_folder, sim_low.h5 and
    sim_high.h5: the low-res sheet waving for `n_frames` frames, and high-res wrinkles that depend on it.
    `transform(positions, frame)` moves both runs rigidly (for the reference-frame tests); `source_mesh` marks the
    three files as made from the sheet."""
    vertices, faces = grid(n)
    marks = {SOURCE_MESH: mesh_fingerprint(vertices, faces)} if source_mesh else {}
    subdivision, high_faces = loop_subdivide(vertices, faces, levels)
    t = np.arange(n_frames)[:, None]
    low = np.repeat(vertices[None], n_frames, axis=0)
    low[:, :, 2] = 0.1 * np.sin(3 * vertices[:, 0] + 0.5 * t) * (1 - vertices[:, 1])
    smooth = np.stack([subdivision @ x for x in low])
    high = smooth + 0.01 * np.sin(12 * smooth[:, :, 0] + 0.3 * t)[..., None] * np.array([0.0, 0.0, 1.0])
    for name, positions, f in (("sim_low", low, faces), ("sim_high", high, high_faces)):
        with atomic_h5(folder / runs_folder / f"{name}.h5", "simulate", SIM_CONFIG) as out:
            out["positions"] = np.stack([transform(p, i) for i, p in enumerate(positions)]).astype(np.float32)
            out["faces"] = f.astype(np.int32)
            out.attrs.update(marks)
    with atomic_h5(folder / "subdiv.h5", "subdivide") as out:
        out.attrs.update(marks)
        write_csr(out, "S", subdivision)
        out["vertices"] = subdivision @ vertices
        out["faces"] = high_faces.astype(np.int32)


def write_sequence_scene(folder: Path, name: str = "train_000", role: str = "train", n_frames: int = N_FRAMES,
                         **datasets) -> None:
    """A sequence's scene.h5 as the dataset stage reads it: which sequence and its role (attrs) and its frame
    count (pin targets of no pins), plus `datasets`."""
    with atomic_h5(folder / "scene.h5", "scene") as f:
        f.attrs.update(sequence=name, role=role)
        f["rest/vertices"] = np.zeros((3, 3))
        f["pins/targets"] = np.zeros((n_frames, 0, 3))
        for dataset, data in datasets.items():
            f[dataset] = data


def stage(main: Callable, *args) -> None:
    """A stage's main the way its command line runs it (pipeline.core.cli.run), its arguments as strings."""
    cli.run(main, [str(a) for a in args])
