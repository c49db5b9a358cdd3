"""Procedural surfaces for the operator tests and benchmarks, each validated on creation: open and closed,
genus zero and one, several boundary loops, regular and irregular valences.

All are consistently oriented counter-clockwise seen from outside; y is up. A scene's own cloth lives with the
scene content (scenes.flag_mesh).
"""
from __future__ import annotations

import numpy as np
import scipy.spatial

from geometry.mesh import validate_mesh


def checked_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`vertices` as float64 and `faces` as int64, after `validate_mesh` accepted them (ValueError otherwise)."""
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    validate_mesh(vertices, faces)
    return vertices, faces


def _grid_faces(nx: int, ny: int) -> np.ndarray:
    """Two counter-clockwise triangles per cell of an nx-by-ny vertex grid indexed i + nx * j."""
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (i + nx * j).ravel()
    b, c, d = a + 1, a + 1 + nx, a + nx
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def grid_patch(nx: int, ny: int, width: float = 1.0, height: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A flat open rectangle hanging in the xy-plane (a flag), normals along +z."""
    x, y = np.meshgrid(np.linspace(0, width, nx), np.linspace(0, height, ny), indexing="xy")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(nx * ny)], axis=1)
    return checked_mesh(vertices, _grid_faces(nx, ny))


def two_triangles() -> tuple[np.ndarray, np.ndarray]:
    return checked_mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])


def cube_sphere(n: int, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Closed sphere: the six n-by-n grids of a cube projected outwards (6 n^2 + 2 vertices)."""
    lattice = np.arange(-n, n + 1, 2)
    points, faces = [], []
    offset = 0
    for axis in range(3):
        for side in (-n, n):
            u, v = np.meshgrid(lattice, lattice, indexing="xy")
            p = np.empty((u.size, 3), dtype=np.int64)
            p[:, axis], p[:, (axis + 1) % 3], p[:, (axis + 2) % 3] = side, u.ravel(), v.ravel()
            points.append(p)
            faces.append(_grid_faces(n + 1, n + 1) + offset)
            offset += len(p)
    points, faces = np.concatenate(points), np.concatenate(faces)
    unique, inverse = np.unique(points, axis=0, return_inverse=True)
    faces = inverse.ravel()[faces]
    vertices = unique / np.linalg.norm(unique, axis=1, keepdims=True) * radius
    return checked_mesh(vertices, _outward(vertices, faces, np.zeros(3)))


def _outward(vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray) -> np.ndarray:
    p = vertices[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    inward = np.einsum("ij,ij->i", normal, p.mean(axis=1) - centre) < 0
    faces = faces.copy()
    faces[inward] = faces[inward][:, ::-1]
    return faces


def torus(n_major: int, n_minor: int, major: float = 1.0, minor: float = 0.35) -> tuple[np.ndarray, np.ndarray]:
    """Closed torus around the y-axis, genus one."""
    u, v = np.meshgrid(np.arange(n_major) * 2 * np.pi / n_major, np.arange(n_minor) * 2 * np.pi / n_minor,
                       indexing="ij")
    ring = major + minor * np.cos(v)
    vertices = np.stack([ring * np.cos(u), minor * np.sin(v), ring * np.sin(u)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = (i * n_minor + j).ravel()
    b = (((i + 1) % n_major) * n_minor + j).ravel()
    c = (((i + 1) % n_major) * n_minor + (j + 1) % n_minor).ravel()
    d = (i * n_minor + (j + 1) % n_minor).ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    p = vertices[faces].mean(axis=1)
    tube_centre = p * 0
    angle = np.arctan2(p[:, 2], p[:, 0])
    tube_centre[:, 0], tube_centre[:, 2] = major * np.cos(angle), major * np.sin(angle)
    normal = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    if np.einsum("ij,ij->i", normal, p - tube_centre).mean() < 0:
        faces = faces[:, ::-1]
    return checked_mesh(vertices, faces)


def pants(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A stretched sphere with three holes cut (waist on top, two legs below): three boundary loops."""
    vertices, faces = cube_sphere(n)
    holes = [(np.array([0.0, 1.0, 0.0]), np.cos(np.radians(40))),
             (np.array([0.7, -1.0, 0.0]), np.cos(np.radians(22))),
             (np.array([-0.7, -1.0, 0.0]), np.cos(np.radians(22)))]
    inside = np.zeros(len(vertices), dtype=bool)
    for direction, cos_radius in holes:
        inside |= vertices @ (direction / np.linalg.norm(direction)) > cos_radius
    faces = faces[~inside[faces].any(axis=1)]
    used = np.unique(faces)
    remap = np.full(len(vertices), -1)
    remap[used] = np.arange(len(used))
    vertices = vertices[used] * np.array([0.4, 0.6, 0.25])
    return checked_mesh(vertices, remap[faces])


def irregular_disk(n_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A bumpy open disk triangulated (Delaunay) over random points: irregular valences and edge lengths."""
    rng = np.random.default_rng(seed)
    n_rim = int(2 * np.sqrt(np.pi * n_points))
    angle = np.arange(n_rim) * 2 * np.pi / n_rim
    rim = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    spacing = 2 * np.pi / n_rim
    inner = []
    while len(inner) < n_points - n_rim:  # dart throwing keeps points apart, so no sliver triangles
        candidate = rng.uniform(-1, 1, size=2)
        if np.linalg.norm(candidate) > 1 - 0.7 * spacing:
            continue
        if inner and np.min(np.linalg.norm(np.asarray(inner) - candidate, axis=1)) < 0.6 * spacing:
            continue
        inner.append(candidate)
    plane = np.concatenate([rim, np.asarray(inner)])
    triangles = scipy.spatial.Delaunay(plane).simplices.astype(np.int64)
    u, v = plane[triangles[:, 1]] - plane[triangles[:, 0]], plane[triangles[:, 2]] - plane[triangles[:, 0]]
    clockwise = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] < 0
    triangles[clockwise] = triangles[clockwise][:, ::-1]
    vertices = np.stack([plane[:, 0], plane[:, 1], 0.15 * np.sin(3 * plane[:, 0]) * np.cos(2 * plane[:, 1])], 1)
    return checked_mesh(vertices, triangles)
