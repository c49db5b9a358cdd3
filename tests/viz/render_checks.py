"""What the render tests draw (a sleeve-like tube, a box of a body) and how they read a picture back (the
cloth's and the body's pixels, the columns of each panel): shared by the render and the comparison tests."""
from __future__ import annotations

import numpy as np


def tube(radius=0.2, height=1.0, around=24, along=12, centre=(0.0, 0.0, 0.0)):
    """An open cylinder along y (a garment-like sleeve)."""
    angle = 2 * np.pi * np.arange(around) / around
    y = np.linspace(0, height, along)
    vertices = np.stack([np.tile(radius * np.cos(angle), along), np.repeat(y, around),
                         np.tile(radius * np.sin(angle), along)], axis=1) + centre
    i, j = np.meshgrid(np.arange(around), np.arange(along - 1), indexing="ij")
    a, b = (i + around * j).ravel(), ((i + 1) % around + around * j).ravel()
    return vertices, np.concatenate([np.stack([a, b, b + around], 1), np.stack([a, b + around, a + around], 1)])


def box(low, high, n=16):
    """A closed box, each side an n x n grid (fine enough that cropping keeps the parts near the garment)."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    vertices, faces = [], []
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    cell = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    for axis in range(3):
        for side in (0.0, 1.0):
            unit = np.zeros((n * n, 3))
            unit[:, axis] = side
            unit[:, (axis + 1) % 3], unit[:, (axis + 2) % 3] = u.ravel(), v.ravel()
            start = sum(len(p) for p in vertices)
            vertices.append(low + unit * (high - low))
            faces.append(start + np.concatenate([np.stack([cell, cell + n, cell + n + 1], 1),
                                                 np.stack([cell, cell + n + 1, cell + 1], 1)]))
    return np.concatenate(vertices), np.concatenate(faces)


def cloth_mask(image):
    """Pixels of the plain cloth colour (blue over red by far) at any shade."""
    rgb = image.astype(float) / 255
    return (rgb[..., 2] > rgb[..., 0] + 0.15) & (rgb[..., 2] > rgb[..., 1])


def body_mask(image):
    """Pixels of the body's muted warm grey (red > green > blue, by little) at any shade."""
    rgb = image.astype(float) / 255
    return ((rgb[..., 0] > rgb[..., 1]) & (rgb[..., 1] > rgb[..., 2]) & (rgb[..., 0] - rgb[..., 2] < 0.15)
            & (rgb[..., 0] > 0.2) & (rgb.max(axis=2) < 0.97))


def column_groups(mask):
    """(first, last) column of each run of columns holding mask pixels: one per panel."""
    columns = np.flatnonzero(mask.any(axis=0))
    breaks = np.flatnonzero(np.diff(columns) > 1)
    return list(zip(columns[np.r_[0, breaks + 1]], columns[np.r_[breaks, len(columns) - 1]]))
