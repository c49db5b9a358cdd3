"""A garment from an artist's file, made a simulation mesh in the mannequin's frame (`mesh.generator:
garment_file`): its units and up axis (given, or read off its size and shape where that is unambiguous), its panels
sewn along their seams, and optionally refined to the scene's max_edge. Arrays in, arrays out: the file is read by
pipeline.core.meshio, the garment is dressed on the body by scenes.dressing.

Units: a garment is between GARMENT_SIZE[0] and GARMENT_SIZE[1] metres across its largest extent (a short top to a
long dress), so a file's largest extent in each candidate unit says which units can be meant; a size that fits
two (centimetres and inches overlap between about 25 and 79) is one error asking for `mesh.units`.
Up axis: a garment hangs along gravity and is flatter front to back than it is long, so of the file's y and z
extents the clearly larger (by UP_RATIO) is up; otherwise one error asking for `mesh.up`. A Z-up file is turned the
way Z-up tools export (Blender: front towards -y) into the mannequin's Y-up frame, front towards +z.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import boundary_loops, unique_edges, validate_mesh, weld_vertices

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
GARMENT_SIZE = (0.25, 2.0)   # metres: the largest extent of any garment a 1.7 m mannequin wears
CLOSED_SURFACE = "a closed surface without openings, not a garment (a garment has a waist, neck or hem)"
MAX_REFINED_FACES = 2_000_000   # mesh.remesh's limit: ~1M vertices, beyond any garment a solver here steps
UP_RATIO = 1.2               # the up axis' extent is at least this many times the other's
# Z-up (x, y, z) -> Y-up (x, z, -y): the front (-y in Blender) becomes +z, the mannequin's front.
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class FileGarment:
    """A garment file's mesh in metres, Y-up, welded (and refined): its vertices keep the file's numbering through
    `file_to_mesh`, so pins named by the file's indices or groups find their vertices."""
    vertices: np.ndarray        # (V, 3) float64, metres, Y-up, front +z
    faces: np.ndarray           # (F, 3) int64
    file_to_mesh: np.ndarray    # (V_file,) int64 the mesh vertex each of the file's vertices became
    units: str                  # the units read or given
    up: str                     # the up axis read or given


def detect_units(vertices: np.ndarray, units: str, size: tuple[float, float] = GARMENT_SIZE,
                 thing: str = "garment") -> str:
    """`units` when given (checked to give a `thing` of `size`, metres across its largest extent), else the one
    unit in which the file's largest extent is such a size; ValueError asking for mesh.units otherwise."""
    extent = float(np.ptp(vertices, axis=0).max())
    low, high = size
    if units != "auto":
        metres = extent * UNITS[units]
        if not low / 2 <= metres <= 2 * high:
            raise ValueError(f"in {units} the {thing} would be {metres:.3g} m across (a {thing} is {low}-{high} m): "
                             f"wrong units? set mesh.units to the file's")
        return units
    fits = [name for name, factor in UNITS.items() if low <= extent * factor <= high]
    if len(fits) == 1:
        return fits[0]
    sizes = ", ".join(f"{extent * factor:.3g} m in {name}" for name, factor in UNITS.items())
    if not fits:
        raise ValueError(f"its largest extent, {extent:.4g} file units, is no {thing}'s size in any unit ({sizes}): "
                         f"not a {thing}, or set mesh.units")
    raise ValueError(f"its largest extent, {extent:.4g} file units, is a {thing}'s size in {' and in '.join(fits)}: "
                     f"set mesh.units to one of {', '.join(UNITS)}")


def detect_up(vertices: np.ndarray, up: str) -> str:
    """`up` when given, else the axis (y or z) whose extent is clearly the larger; ValueError asking for mesh.up."""
    if up != "auto":
        return up
    extent = np.ptp(vertices, axis=0)
    if extent[1] >= UP_RATIO * extent[2]:
        return "y"
    if extent[2] >= UP_RATIO * extent[1]:
        return "z"
    raise ValueError(f"its y and z extents ({extent[1]:.4g}, {extent[2]:.4g} file units) are too alike to tell which "
                     f"is up: set mesh.up to y or z")


def garment_from_file(vertices: np.ndarray, faces: np.ndarray, units: str, up: str, weld: float,
                      max_edge: float | None) -> FileGarment:
    """The file's mesh in metres and Y-up, its vertices closer than `weld` metres merged (panels sewn along their
    seams) and, with `max_edge`, refined by midpoint subdivision until every edge is shorter (the file's vertices
    stay, first and in their order). ValueError for a mesh the solver cannot take (non-manifold, inconsistently
    oriented, degenerate), naming the problem in the welded mesh."""
    if not boundary_loops(len(vertices), np.asarray(faces)):
        raise ValueError(CLOSED_SURFACE)
    units, up = detect_units(vertices, units), detect_up(vertices, up)
    metres = np.asarray(vertices, dtype=np.float64) * UNITS[units]
    if up == "z":
        metres = metres @ Z_UP_TO_Y_UP.T
    welded, faces, file_to_mesh = weld_vertices(metres, faces, weld)
    try:
        validate_mesh(welded, faces)
    except ValueError as err:
        raise ValueError(f"not a mesh the cloth solver can take once welded within {weld:g} m: {err}") from None
    edges = unique_edges(faces)
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(welded),) * 2)
    pieces = csgraph.connected_components(graph, directed=False)[0]
    if pieces > 1:
        raise ValueError(f"{pieces} separate pieces once welded within {weld:g} m: a garment is one piece; panels "
                         f"whose seam vertices are duplicated are sewn by mesh.weld (a tolerance above the gap "
                         f"between the copies, below the shortest edge)")
    if max_edge is not None:
        welded, faces = refine_to_edge(welded, faces, max_edge)
    return FileGarment(welded, faces, file_to_mesh, units, up)


def refine_to_edge(vertices: np.ndarray, faces: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision of every face, repeated until every edge is shorter than max_edge: old vertices keep
    their indices, each edge's midpoint is appended once (so the mesh stays manifold and oriented). ValueError
    when that would make more than MAX_REFINED_FACES faces (each round quadruples them)."""
    edges = unique_edges(faces)
    longest = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).max()
    rounds = max(0, int(np.floor(np.log2(longest / max_edge))) + 1)
    if len(faces) * 4 ** rounds > MAX_REFINED_FACES:
        raise ValueError(f"refining its {len(faces):,} faces to max_edge {max_edge:g} m takes {rounds} rounds of "
                         f"midpoint subdivision, beyond {MAX_REFINED_FACES:,} faces: raise max_edge or set "
                         f"mesh.remesh false")
    while True:
        directed = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1)      # (F, 3, 2)
        edges, edge_of = np.unique(np.sort(directed, axis=2).reshape(-1, 2), axis=0, return_inverse=True)
        if np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1).max() < max_edge:
            return vertices, faces
        ab, bc, ca = (len(vertices) + edge_of.reshape(-1, 3)).T
        a, b, c = faces.T
        vertices = np.concatenate([vertices, 0.5 * (vertices[edges[:, 0]] + vertices[edges[:, 1]])])
        faces = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
