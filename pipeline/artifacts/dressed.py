"""dressed.h5, written by the `dress` stage (results/<scene>/dressed.h5, a `garment_file` scene only): the user's
garment settled on the rest-pose mannequin, which the scene stage takes as the scene's rest mesh, and how it got
there (docs/artifacts.md, section "dressed.h5"). The dataset paths are named here and nowhere else."""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from pipeline.core.h5 import atomic_h5, open_artifact, read, read_indices
from scenes.garments import Garment

STAGE = "dress"
VERTICES, FACES = "vertices", "faces"                    # the settled garment: the scene's rest mesh
PIN_IDS, PIN_PART = "pins/ids", "pins/part"              # pinned vertices and the body part each follows
PLACED = "placed"                                        # the file's mesh placed on the body, before the settle
SETTLE_STAGES = "settle/stages"                          # the cloth at the end of each settle stage
SETTLE_CLEARANCE = "settle/clearance"                    # each stage's least distance to the body


@dataclass(frozen=True, eq=False)
class Dressed:
    garment: Garment              # kind "file": the settled mesh, its pins as attachment
    placed: np.ndarray            # (V, 3) the file's mesh placed on the body, before the settle
    stages: np.ndarray            # (STAGES, V, 3)
    clearance: np.ndarray         # (STAGES,) metres; negative: inside the body
    attrs: dict[str, Any]         # file, sha256, units, up, anchor, scale, offset, weld, edge_change_*


def write_dressed(path: str | os.PathLike, dressed: Dressed, settings: Mapping[str, Any]) -> None:
    g = dressed.garment
    with atomic_h5(path, STAGE, settings) as f:
        f.create_dataset(VERTICES, data=g.vertices.astype(np.float64))
        f.create_dataset(FACES, data=g.faces.astype(np.int32))
        f.create_dataset(PIN_IDS, data=g.attachment.astype(np.int32))
        f.create_dataset(PIN_PART, data=g.attachment_part.astype(np.int32))
        f.create_dataset(PLACED, data=dressed.placed.astype(np.float64))
        f.create_dataset(SETTLE_STAGES, data=dressed.stages.astype(np.float32))
        f.create_dataset(SETTLE_CLEARANCE, data=dressed.clearance.astype(np.float64))
        f.attrs.update(dressed.attrs)


def read_dressed_garment(path: str | os.PathLike, n_parts: int) -> Garment:
    """The settled garment and its pins, checked (indices in range, finite positions, parts of a skeleton of
    `n_parts`)."""
    with open_artifact(path) as f:
        vertices = read(f, VERTICES, np.float64)
        faces = read_indices(f, FACES, len(vertices), shape=(None, 3))
        ids = read_indices(f, PIN_IDS, len(vertices), shape=(None,))
        part = read_indices(f, PIN_PART, n_parts, shape=(len(ids),))
    return Garment("file", vertices, faces.astype(np.int64), ids.astype(np.int64), part)
