"""Garment files with the traits of artists' exports, written by the tests (of tests/scenes and tests/pipeline):
a procedural garment (scenes.garments) cut into panels with duplicated seam vertices, one OBJ group per panel
and a group for its waistband or collar, in centimetres, inches or metres, Y-up or Z-up (turned as Blender
exports: front towards -y), moved off the origin. `where_worn` gives back the positions the file's vertices
had on the mannequin, to compare a dressed garment with."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import unique_edges
from scenes.garments import make_garment

UNIT_METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
# Y-up (x, y, z) -> Z-up (x, -z, y): the inverse of scenes.garment_file.Z_UP_TO_Y_UP, written independently.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
ATTACHMENT_GROUP = "band"


def write_garment_obj(path: Path, kind: str, max_edge: float, units: str = "m", up: str = "y",
                      offset=(0.0, 0.0, 0.0), panels: bool = True, band_group: bool = True,
                      seam_gap: float = 0.0) -> np.ndarray:
    """Write `kind` as an artist's OBJ; returns the file's vertices as they were worn on the mannequin (metres,
    Y-up), in file order. `seam_gap` (metres): the k-th seam copy of a vertex moves k gaps along x, as in exports
    whose panels do not quite meet."""
    garment = make_garment(kind, max_edge=max_edge, panels=panels)
    worn, faces = garment.vertices.copy(), garment.faces
    first = np.r_[True, (np.diff(worn, axis=0) != 0).any(axis=1)]   # copies follow their first (cut_along_edges)
    start = np.maximum.accumulate(np.where(first, np.arange(len(worn)), 0))
    worn[:, 0] += seam_gap * (np.arange(len(worn)) - start)
    stored = (worn + np.asarray(offset)) / UNIT_METRES[units]
    if up == "z":
        stored = stored @ Y_UP_TO_Z_UP.T
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(worn),) * 2)
    _, piece = csgraph.connected_components(graph, directed=False)
    # The waistband or collar as a group of its own: the faces with a corner on the attachment (a face belongs to
    # one group, so the panels list the others).
    band = np.isin(faces, garment.attachment).any(axis=1) if band_group else np.zeros(len(faces), dtype=bool)
    lines = [f"# {kind} exported in {units}, {up} up", "mtllib garment.mtl"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in stored]
    lines += [f"vt {u:.4f} {v:.4f}" for u, v in np.random.default_rng(0).random((len(worn), 2))]
    for name, members in [*((f"panel_{p}", (piece[faces[:, 0]] == p) & ~band) for p in range(piece.max() + 1)),
                          (ATTACHMENT_GROUP, band)]:
        if members.any():
            lines += [f"g {name}", "usemtl cloth"]
            lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in faces[members]]
    path.write_text("\n".join(lines) + "\n")
    return worn
