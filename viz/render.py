"""Shaded renders of cloth on a body: panels side by side, framed on the garment, as an RGB array or a PNG.

Camera: orthographic, looking from `View.azimuth` degrees around the scene's up axis (y; 0 looks from +z, positive
turns towards +x) and `View.elevation` degrees above the horizontal. `fit_view` frames the garment alone, tightly;
the body (a panel's `backdrop`) never widens the frame: the picture cuts it at the garment's bounds plus a margin,
and body faces nearer to the camera than the garment's nearest point (plus the margin) are left out, so that a
hand passing in front cannot hide the cloth; behind the garment the body is kept whole. Fit one view to every
frame of a sequence and pass it to each render, and an animation keeps a still camera. A flat cloth (a sheet, a
flag) is never seen edge-on: the camera turns until it sees the cloth's plane at FLAT_VIEW_ANGLE or more.

Visibility is exact per pixel (viz/raster.py's z-buffer, supersampled for smooth edges), so the body (muted warm
grey, outlined) shows inside the cloth's outline only where it truly is in front of the cloth: the cloth's far side
behind a limb, or cloth that has gone into the body (penetration), never a depth-sorting artefact. Lights are
fixed to the camera (a key light from the upper left, a weak fill from the right, a faint highlight) and shading is
two-sided (the side the camera sees is lit), with normals interpolated per pixel, so folds read at any azimuth; a
dark line marks every depth jump (silhouettes, folds overlapping, cloth against body) but not a smooth surface
seen at a grazing angle. Coloured panels (`Panel.values`) share one labelled colour bar from 0 to vmax.

Layout: every panel has the same size, `panel_height` inches tall and as wide as the view's aspect asks, so the
figure is mostly cloth: titles take a thin strip above the panels and the colour bar a narrow one at the right.
"""
from __future__ import annotations

import dataclasses
import io
from pathlib import Path
from typing import Sequence

import matplotlib.image
import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from viz.raster import EMPTY, rasterize

CLOTH_RGB = np.array([0.33, 0.53, 0.86])
BODY_RGB = np.array([0.76, 0.72, 0.67])
BACKGROUND_RGB = np.array([1.0, 1.0, 1.0])
ERROR_CMAP = "inferno"
OUTLINE_SHADE = 0.3            # colour factor on the pixels either side of a depth jump
OUTLINE_JUMP = 4.0             # a depth step this many pixel widths beyond the surface's slope is a jump
# Lights in camera coordinates (right, up, towards the viewer), as weights: ambient, key (upper left), fill (right).
KEY_LIGHT = np.array([-0.45, 0.6, 0.66]) / np.linalg.norm([-0.45, 0.6, 0.66])
FILL_LIGHT = np.array([0.7, 0.0, 0.71]) / np.linalg.norm([0.7, 0.0, 0.71])
AMBIENT, KEY, FILL, HIGHLIGHT, HIGHLIGHT_POWER = 0.22, 0.62, 0.2, 0.12, 24.0
# A cloth whose thinnest principal spread is at most FLAT_SPREAD of its widest is flat, and is seen at least
# FLAT_VIEW_ANGLE degrees off its plane (fit_view).
FLAT_SPREAD, FLAT_VIEW_ANGLE = 0.25, 45.0
# Layout, in inches.
TITLE_STRIP, SUPTITLE_STRIP, GAP, COLORBAR_STRIP, COLORBAR_WIDTH = 0.32, 0.36, 0.12, 1.05, 0.16
PANEL_EDGE = "0.8"             # a thin frame keeps neighbouring panels apart where the body reaches the edge


@dataclasses.dataclass(frozen=True)
class Panel:
    """One mesh in a figure; `values` (V,) colours it (e.g. per-vertex error), else it is plain shaded cloth.
    A `backdrop` mesh (vertices, faces), e.g. the body wearing the garment, is drawn around it, cropped."""

    title: str
    vertices: np.ndarray
    faces: np.ndarray
    values: np.ndarray | None = None
    backdrop: tuple[np.ndarray, np.ndarray] | None = None


@dataclasses.dataclass(frozen=True)
class View:
    """A fixed camera: the direction it looks from, the window of the picture plane it shows (scene units,
    (u_min, u_max, v_min, v_max), u right, v up) and the depth (towards the viewer) beyond which backdrop faces
    are left out."""

    elevation: float
    azimuth: float
    window: tuple[float, float, float, float]
    nearest: float


def camera_axes(elevation: float, azimuth: float) -> np.ndarray:
    """Rows: the picture's right, its up and the direction towards the viewer, in scene coordinates (y up)."""
    el, az = np.radians(elevation), np.radians(azimuth)
    towards = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
    right = np.array([np.cos(az), 0.0, -np.sin(az)])
    return np.stack([right, np.cross(towards, right), towards])


def fit_view(garment_points: Sequence[np.ndarray], elevation: float = 12.0, azimuth: float = 30.0,
             margin: float = 0.04, flat_angle: float = FLAT_VIEW_ANGLE) -> View:
    """The tightest view showing every garment point given (arrays (..., 3): one frame, or all frames of a
    sequence for a camera that stays still), plus `margin` times the garment's size on every side.

    A flat cloth (a sheet, a flag) that the camera would see less than `flat_angle` degrees off its plane is seen
    from that angle instead (see `facing_flat_cloth`); any other garment is seen from `elevation`, `azimuth`."""
    points = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in garment_points])
    if len(points) == 0 or not np.isfinite(points).all():
        raise ValueError("fit_view needs finite garment points")
    elevation, azimuth = facing_flat_cloth(points, elevation, azimuth, flat_angle)
    pad = margin * max(float(np.max(np.ptp(points, axis=0))), 1e-9)
    seen = points @ camera_axes(elevation, azimuth).T
    (u0, v0, _), (u1, v1, nearest) = seen.min(axis=0) - pad, seen.max(axis=0) + pad
    return View(elevation, azimuth, (float(u0), float(u1), float(v0), float(v1)), float(nearest))


def facing_flat_cloth(points: np.ndarray, elevation: float, azimuth: float,
                      flat_angle: float) -> tuple[float, float]:
    """The camera's (elevation, azimuth), turned as little as possible so that it sees a flat cloth at least
    `flat_angle` degrees off the cloth's plane, from the side it already sees; unchanged for a cloth it already
    sees that well and for any garment that is not flat.

    Seen nearly edge-on a sheet is a sliver: a panel up to three times as wide as tall (the aspect's cap), the
    cloth a thin strip across it. Flat means that the points' thinnest principal spread is at most FLAT_SPREAD
    of their widest: a garment around a body (pants: about 0.4) keeps the scene's camera.
    """
    centred = points - points.mean(axis=0)
    variances, directions = np.linalg.eigh(centred.T @ centred)                  # ascending
    if variances[2] <= 0 or variances[0] > FLAT_SPREAD ** 2 * variances[2]:
        return elevation, azimuth
    normal, towards = directions[:, 0], camera_axes(elevation, azimuth)[2]
    if towards @ normal < 0:
        normal = -normal                                                          # the side the camera sees
    if towards @ normal >= np.sin(np.radians(flat_angle)):
        return elevation, azimuth
    in_plane = towards - (towards @ normal) * normal
    angle = np.radians(flat_angle)
    turned = np.cos(angle) * in_plane / np.linalg.norm(in_plane) + np.sin(angle) * normal
    elevation = np.degrees(np.arcsin(np.clip(turned[1], -1.0, 1.0)))
    return float(elevation), float(np.degrees(np.arctan2(turned[0], turned[2])))


def value_colors(values: np.ndarray, vmax: float, cmap: str = ERROR_CMAP) -> np.ndarray:
    """RGBA (N, 4) of values on a 0..vmax colour scale."""
    return colormaps[cmap](np.clip(np.asarray(values) / max(vmax, 1e-30), 0.0, 1.0))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3); zero for a vertex of no face."""
    corners = vertices[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])   # length: 2 x area
    normals = np.stack([np.bincount(faces.ravel(), np.repeat(face_normals[:, k], 3), len(vertices))
                        for k in range(3)], axis=1)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)


def shading(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse intensity in [0, 1] and white highlight of unit normals given in camera coordinates (..., 3).
    Two-sided: a normal facing away from the viewer is turned round first (cloth is seen from both sides)."""
    normals = np.where(normals[..., 2:3] < 0, -normals, normals)
    diffuse = AMBIENT + KEY * np.maximum(normals @ KEY_LIGHT, 0) + FILL * np.maximum(normals @ FILL_LIGHT, 0)
    halfway = (KEY_LIGHT + [0, 0, 1]) / np.linalg.norm(KEY_LIGHT + [0, 0, 1])
    return np.minimum(diffuse, 1.0), HIGHLIGHT * np.maximum(normals @ halfway, 0) ** HIGHLIGHT_POWER


def panel_pixels(panel: Panel, view: View, width: int, height: int, vmax: float = 1.0,
                 supersample: int = 2) -> np.ndarray:
    """RGB floats (height, width, 3) of one panel seen through `view`, window centred and scaled to fit."""
    axes = camera_axes(view.elevation, view.azimuth)
    meshes = [(np.asarray(panel.vertices, dtype=np.float64), np.asarray(panel.faces))]
    if panel.backdrop is not None:
        vertices, faces = np.asarray(panel.backdrop[0], dtype=np.float64), np.asarray(panel.backdrop[1])
        meshes.append((vertices, faces[(vertices @ axes[2])[faces].mean(axis=1) <= view.nearest]))
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    vertices = np.concatenate([v for v, _ in meshes]) @ axes.T                           # camera coordinates
    triangles = np.concatenate([f + o for (_, f), o in zip(meshes, offsets)])
    normals = np.concatenate([vertex_normals(v, f) for v, f in meshes]) @ axes.T
    w, h = width * supersample, height * supersample
    u0, u1, v0, v1 = view.window
    scale = min(w / max(u1 - u0, 1e-12), h / max(v1 - v0, 1e-12))                    # pixels per scene unit
    screen = np.stack([(vertices[:, 0] - (u0 + u1) / 2) * scale + w / 2,
                       h / 2 - (vertices[:, 1] - (v0 + v1) / 2) * scale, vertices[:, 2]], axis=1)
    seen = rasterize(screen, triangles, h, w)
    hit = np.flatnonzero(seen.triangle.ravel() != EMPTY)
    seen_triangle, weights = seen.triangle.ravel()[hit], seen.barycentric.reshape(-1, 3)[hit]
    normal = _interpolate(normals.astype(np.float32), triangles, seen_triangle, weights)
    diffuse, highlight = shading(normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30))
    on_cloth = seen_triangle < len(meshes[0][1])
    colour = np.where(on_cloth[:, None], CLOTH_RGB * diffuse[:, None] + highlight[:, None],
                      BODY_RGB * diffuse[:, None])
    if panel.values is not None:
        values = np.asarray(panel.values, dtype=np.float32)[:, None]
        if values.shape[0] != len(meshes[0][0]):
            raise ValueError(f"panel {panel.title!r}: {values.shape[0]} values for {len(meshes[0][0])} vertices")
        value = _interpolate(values, triangles, seen_triangle[on_cloth], weights[on_cloth])[:, 0]
        colour[on_cloth] = value_colors(value, vmax)[:, :3] * (0.5 + 0.5 * diffuse[on_cloth, None])
    rgb = np.tile(BACKGROUND_RGB.astype(np.float32), (h * w, 1))
    rgb[hit] = np.clip(colour, 0.0, 1.0)
    rgb = rgb.reshape(h, w, 3)
    surface = np.where(seen.triangle == EMPTY, -1, np.where(seen.triangle < len(meshes[0][1]), 0, 1))
    rgb[_depth_jumps(surface, seen.depth, OUTLINE_JUMP / scale)] *= OUTLINE_SHADE
    return sum(rgb[i::supersample, j::supersample] for i in range(supersample)
               for j in range(supersample)) / supersample ** 2


def _interpolate(per_vertex: np.ndarray, triangles: np.ndarray, triangle_ids: np.ndarray,
                 weights: np.ndarray) -> np.ndarray:
    """(P, k) values of (N, k) `per_vertex` at P points given by triangle and barycentric weights (np.take: much
    faster than fancy indexing at a million points)."""
    return sum(weights[:, k:k + 1] * np.take(per_vertex, np.take(triangles[:, k], triangle_ids), axis=0)
               for k in range(3))


def _depth_jumps(surface: np.ndarray, depth: np.ndarray, jump: float) -> np.ndarray:
    """(H, W) bool: pixels next to a neighbour (right or below) on another surface (cloth, body, nothing), and
    pixels where the depth along a row or column steps by more than `jump` beyond what the surface's own slope
    explains (its second difference: a sheet seen at a grazing angle changes depth by many pixel widths per pixel,
    but evenly, and is no outline). Both pixels of a step are marked, for a line that survives downsampling."""
    marked = np.zeros(surface.shape, dtype=bool)
    for axis in (0, 1):
        ahead, behind = _along(axis, 1, None), _along(axis, None, -1)
        changed = surface[ahead] != surface[behind]
        marked[ahead] |= changed
        marked[behind] |= changed
        before, centre, after = _along(axis, None, -2), _along(axis, 1, -1), _along(axis, 2, None)
        one_surface = ((surface[centre] >= 0) & (surface[before] == surface[centre])
                       & (surface[after] == surface[centre]))
        with np.errstate(invalid="ignore"):                         # -inf where a pixel is empty
            bend = np.abs(depth[after] - 2 * depth[centre] + depth[before])
        marked[centre] |= one_surface & (bend > jump)
    return marked


def _along(axis: int, start: int | None, stop: int | None) -> tuple[slice, slice]:
    """The index of an image's rows (axis 0) or columns (axis 1) start:stop, all of the other axis."""
    cut = [slice(None), slice(None)]
    cut[axis] = slice(start, stop)
    return tuple(cut)


def panels_image(panels: Sequence[Panel], view: View | None = None, vmax: float | None = None,
                 title: str | None = None, value_label: str = "error", panel_height: float = 4.5,
                 dpi: int = 100, supersample: int = 2) -> np.ndarray:
    """RGB uint8 (H, W, 3) of the panels side by side, all through one view (default: `fit_view` of the
    panels' meshes, backdrops excluded); coloured panels share a colour bar from 0 to `vmax` (default: the largest
    value shown), labelled `value_label`. Each panel is `panel_height` inches tall at `dpi` pixels per inch."""
    if not panels:
        raise ValueError("panels_image needs at least one panel")
    view = view or fit_view([p.vertices for p in panels])
    coloured = [p.values for p in panels if p.values is not None]
    if vmax is None:
        vmax = float(max((np.max(v) for v in coloured), default=1.0))
    vmax = max(vmax, 1e-12)                     # all-zero errors (a rest frame) still get a colour bar
    u0, u1, v0, v1 = view.window
    height = int(round(panel_height * dpi))
    width = int(round(height * np.clip((u1 - u0) / max(v1 - v0, 1e-12), 0.3, 3.0)))
    # Whole pixels everywhere, so that each panel's image lands on the canvas unresampled.
    top = round((TITLE_STRIP + (SUPTITLE_STRIP if title else 0.0)) * dpi)
    right = round(COLORBAR_STRIP * dpi) if coloured else 0
    gap = round(GAP * dpi)
    fig_w, fig_h = len(panels) * width + (len(panels) - 1) * gap + right, height + top
    fig = Figure(figsize=(fig_w / dpi, fig_h / dpi), dpi=dpi, facecolor=BACKGROUND_RGB)
    canvas = FigureCanvasAgg(fig)
    for i, panel in enumerate(panels):
        ax = fig.add_axes((i * (width + gap) / fig_w, 0.0, width / fig_w, height / fig_h))
        ax.imshow(panel_pixels(panel, view, width, height, vmax, supersample), interpolation="none")
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_edgecolor(PANEL_EDGE)
        ax.set_title(panel.title, fontsize=12, pad=4)
    if coloured:
        bar_left = (fig_w - right + 0.12 * dpi) / fig_w
        bar_ax = fig.add_axes((bar_left, 0.06, COLORBAR_WIDTH * dpi / fig_w, 0.88 * height / fig_h))
        bar = fig.colorbar(ScalarMappable(Normalize(0, vmax), cmap=ERROR_CMAP), cax=bar_ax)
        bar.set_label(value_label, fontsize=11)
        bar.ax.tick_params(labelsize=10)
    if title:
        fig.suptitle(title, fontsize=14, y=1 - 0.06 * dpi / fig_h, va="top")
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def png_bytes(image: np.ndarray) -> bytes:
    """A PNG file's bytes of an RGB uint8 image (H, W, 3), for an atomic write or a data: URI."""
    buffer = io.BytesIO()
    matplotlib.image.imsave(buffer, image, format="png")
    return buffer.getvalue()


def render_panels(path: str | Path, panels: Sequence[Panel], vmax: float | None = None, title: str | None = None,
                  value_label: str = "error", view: View | None = None, panel_height: float = 4.5,
                  dpi: int = 100) -> Path:
    """`panels_image` written to `path` as a PNG (not atomically: a stage writes `png_bytes(panels_image(...))`
    through its atomic writer instead)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png_bytes(panels_image(panels, view, vmax, title, value_label, panel_height, dpi)))
    return path
