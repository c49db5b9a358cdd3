"""Shaded renders of triangle meshes with matplotlib's Agg canvas (no display, no pyplot global state).

Scenes are y-up; matplotlib's 3D axes are z-up, so a scene point (x, y, z) is drawn at (x, -z, y), a rotation
that keeps the mesh's handedness and thus its face orientation.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

LIGHT = np.array([0.35, 0.8, 0.5]) / np.linalg.norm([0.35, 0.8, 0.5])   # scene frame, from above and in front
SURFACE_RGB = np.array([0.62, 0.72, 0.86])
BACKDROP_RGB = np.array([0.80, 0.76, 0.70])
ERROR_CMAP = "inferno"


@dataclasses.dataclass(frozen=True)
class Panel:
    """One mesh in a figure; `values` (V,) colours it (e.g. per-vertex error), else it is plain shaded. A
    `backdrop` mesh (vertices, faces), e.g. the body wearing the garment, is drawn in grey behind and around it."""

    title: str
    vertices: np.ndarray
    faces: np.ndarray
    values: np.ndarray | None = None
    backdrop: tuple[np.ndarray, np.ndarray] | None = None


def face_shading(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Two-sided Lambert intensity per face in [0.3, 1] (cloth is seen from both sides)."""
    v = vertices[faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    return 0.3 + 0.7 * np.abs(normals @ LIGHT)


def value_colors(values: np.ndarray, vmax: float, cmap: str = ERROR_CMAP) -> np.ndarray:
    """RGBA (N, 4) of values on a 0..vmax colour scale."""
    return colormaps[cmap](np.clip(np.asarray(values) / max(vmax, 1e-30), 0.0, 1.0))


def _to_plot(points: np.ndarray) -> np.ndarray:
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def render_panels(path: str | Path, panels: list[Panel], vmax: float | None = None, title: str | None = None,
                  value_label: str = "error", elevation: float = 18.0, azimuth: float = -62.0) -> Path:
    """A PNG of the panels side by side, all with the same view and scale; coloured panels share a colour bar
    from 0 to `vmax` (default: the largest value shown)."""
    coloured = [p.values for p in panels if p.values is not None]
    if vmax is None and coloured:
        vmax = float(max(np.max(v) for v in coloured))
    everything = np.concatenate([p.vertices for p in panels] + [p.backdrop[0] for p in panels if p.backdrop])
    low, high = everything.min(axis=0), everything.max(axis=0)
    centre, half = (low + high) / 2, max(float(np.max(high - low)) / 2, 1e-9)
    fig = Figure(figsize=(3.0 * len(panels) + (0.6 if coloured else 0), 3.3), dpi=110)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.0, right=0.92 if coloured else 1.0, bottom=0.0, top=0.88, wspace=0.0)
    for i, panel in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1, projection="3d")
        shade = face_shading(panel.vertices, panel.faces)[:, None]
        if panel.values is None:
            rgb = SURFACE_RGB * shade
        else:
            rgb = value_colors(panel.values[panel.faces].mean(axis=1), vmax)[:, :3] * (0.55 + 0.45 * shade)
        triangles = panel.vertices[panel.faces]
        if panel.backdrop is not None:
            # One collection, so that matplotlib's painter's sort orders body and cloth faces together.
            vertices, faces = panel.backdrop
            triangles = np.concatenate([vertices[faces], triangles])
            rgb = np.concatenate([BACKDROP_RGB * face_shading(vertices, faces)[:, None], rgb])
        # Edges drawn in the face colour hide the hairline seams antialiasing leaves between faces.
        ax.add_collection3d(Poly3DCollection(_to_plot(triangles), facecolors=rgb, edgecolors=rgb, linewidths=0.3))
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), _to_plot(centre)):
            setter(c - half, c + half)
        ax.set_box_aspect((1, 1, 1), zoom=1.1)
        ax.view_init(elev=elevation, azim=azimuth)
        ax.set_axis_off()
        ax.set_title(panel.title, fontsize=9)
    if coloured:
        bar = fig.colorbar(ScalarMappable(Normalize(0, vmax), cmap=ERROR_CMAP), ax=fig.axes, shrink=0.7, pad=0.02)
        bar.set_label(value_label, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path
