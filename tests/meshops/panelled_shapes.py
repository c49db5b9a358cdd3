"""Meshes modelled as an artist's garment export is: separate panels whose seam vertices are duplicated at the same
positions, panels that meet themselves along a seam (a cuff or waistband closed by one seam, a dart), slivers and
tiny pieces. Each builder returns (vertices, faces), validated."""
from __future__ import annotations

import functools

import numpy as np

from geometry.mesh import cut_along_edges, edge_faces
from geometry.shapes import checked_mesh, cube_sphere, grid_patch, pants
from scenes.garments import make_garment


def sewn_tube(columns: int, rows: int, radius: float = 0.1, height: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """A tube of `columns` quads around and `rows` rings, closed by one seam: its last column of vertices
    duplicates the first at exactly the same positions. Normals point outward."""
    angle = 2 * np.pi * np.arange(columns + 1) / columns
    angle[-1] = 0.0   # the seam copies, bit for bit
    y = np.linspace(0.0, height, rows)
    vertices = np.stack(np.broadcast_arrays(radius * np.cos(angle)[None], y[:, None], radius * np.sin(angle)[None]),
                        axis=-1).reshape(-1, 3)
    index = np.arange(rows * (columns + 1)).reshape(rows, columns + 1)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return checked_mesh(vertices, np.concatenate([np.stack([a, d, b], 1), np.stack([a, c, d], 1)]))


def voronoi_panels(vertices: np.ndarray, faces: np.ndarray, n_panels: int, seed: int = 0
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The mesh cut into `n_panels` panels (faces nearest the same random seed face), seam vertices duplicated."""
    centre = vertices[faces].mean(axis=1)
    seeds = centre[np.random.default_rng(seed).choice(len(faces), n_panels, replace=False)]
    panel = np.argmin(np.linalg.norm(centre[:, None] - seeds[None], axis=-1), axis=1)
    edges, sides = edge_faces(faces)
    seam = (sides[:, 1] >= 0) & (panel[sides[:, 0]] != panel[np.maximum(sides[:, 1], 0)])
    return cut_along_edges(vertices, faces, edges[seam])[:2]


def darted_patch(size: float) -> tuple[np.ndarray, np.ndarray]:
    """A square panel with a dart: a slit cut from the middle of one border halfway in, its vertices duplicated
    but for the inner end, so the panel meets itself along the slit."""
    vertices, faces = grid_patch(7, 7, size, size)   # vertex i + 7 j
    slit = 3 + 7 * np.arange(4)
    return cut_along_edges(vertices, faces, np.stack([slit[:-1], slit[1:]], axis=1))[:2]


def tiny_pieces(size: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A single triangle, a single quad, a sliver triangle (height 1e-4 of its base), a strip of slivers and a
    patch a thousandth of `size` across."""
    triangle = checked_mesh([[0, 0, 0], [size, 0, 0], [0, size, 0]], [[0, 1, 2]])
    sliver = checked_mesh([[0, 0, 0], [size, 0, 0], [size / 2, size * 1e-4, 0]], [[0, 1, 2]])
    return [triangle, grid_patch(2, 2, size, size), sliver, grid_patch(8, 2, 4 * size, size / 50),
            grid_patch(3, 3, size / 1000, size / 1000)]


def gathered(pieces: list[tuple[np.ndarray, np.ndarray]], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Pieces side by side in one mesh, each turned and moved a little so that none shares a plane by accident."""
    rng = np.random.default_rng(seed)
    vertices, faces, count = [], [], 0
    for points, triangles in pieces:
        turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        turn *= np.sign(np.linalg.det(turn))
        vertices.append(points @ turn.T + rng.normal(scale=0.5, size=3))
        faces.append(triangles + count)
        count += len(points)
    return checked_mesh(np.concatenate(vertices), np.concatenate(faces))


def _panelled_pants() -> tuple[np.ndarray, np.ndarray]:
    return gathered([voronoi_panels(*pants(12), 12), *tiny_pieces(0.1), sewn_tube(5, 4), darted_patch(0.3)])


def _sewn_tubes() -> tuple[np.ndarray, np.ndarray]:
    return gathered([sewn_tube(columns, rows) for columns in (3, 4, 6, 9) for rows in (2, 6)])


def _panelled_cape() -> tuple[np.ndarray, np.ndarray]:
    """The procedural cape as panels (scenes.garments): its centre-back seam cuts the top band only partway (a
    slit), so a seam copy lies two rings from its twin, and the operators stage failed on it (NaN ring dummy)."""
    garment = make_garment("cape", max_edge=0.08, panels=True)
    return garment.vertices, garment.faces


def _large() -> tuple[np.ndarray, np.ndarray]:
    """10k+ vertices: a sphere in a dozen panels, sewn tubes and tiny pieces."""
    return gathered([voronoi_panels(*cube_sphere(40), 12), *tiny_pieces(0.05), sewn_tube(4, 6), sewn_tube(6, 3),
                     darted_patch(0.2)])


PANELLED_MESHES = {"panelled_pants": _panelled_pants, "sewn_tubes": _sewn_tubes, "panelled_cape": _panelled_cape,
                   "large": _large}


@functools.lru_cache(maxsize=None)
def panelled_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    return PANELLED_MESHES[name]()
