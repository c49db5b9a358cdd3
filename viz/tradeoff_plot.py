"""The speed-accuracy figure: error against ms per frame (log-log), every configuration a labelled point whose
marker says what it is (learned path by training input, Loop subdivision alone, a cheaper high-res run), the
Pareto front drawn and the reference high-res run's ms as a line, so that a person sees at a glance which one to
pick for a budget; where the learned paths were also timed with the fused network (CUDA), those times as hollow
markers and their front dotted: what a user deploys there."""
from __future__ import annotations

import dataclasses
import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

MARKERS = ("o", "^", "s", "D", "v", "P", "X")
LABEL_SIZE = 7                      # points
MARKER_HALF = 3.0                   # half a scatter marker's width (its default size, 36 points^2), in points
# Where a label may go, in points from its point, tried in order: up and right of it, then further below and above
# (a cluster of points at one budget, the networks and Loop subdivision at 8 substeps, needs the far ones).
LABEL_OFFSETS = ((4, 4), (4, -11), (4, 15), (4, -22), (4, 26), (4, -33), (4, 37), (4, -44), (4, 48), (4, -55),
                 (4, 59))
# A label whose box is further than this from its point (points) is joined to it by a line: near a cluster a label
# a few lines away would otherwise read as another point's.
LEADER_GAP = 7.0
LEADER = {"arrowstyle": "-", "color": "0.45", "linewidth": 0.5, "shrinkA": 0.0, "shrinkB": MARKER_HALF}
COLOURS = ("tab:blue", "tab:orange", "tab:gray", "tab:green", "tab:purple", "tab:brown", "tab:pink")


@dataclasses.dataclass(frozen=True)
class Faster:
    """The same points timed again with a faster part (the fused network on CUDA): `ms` per point (NaN where not
    timed again), `fronts` split -> the Pareto front mask with those ms, `label` what the faster part is, `first`
    what the first timing had in its place."""

    ms: np.ndarray
    fronts: dict[str, np.ndarray]
    label: str
    first: str


def tradeoff_plot(labels: list[str], ms: np.ndarray, errors: dict[str, np.ndarray], fronts: dict[str, np.ndarray],
                  groups: list[str], reference_ms: float | None = None, reference_label: str = "high-res reference",
                  unit: str = "L1 (x 1e-3 scene units)", fast: Faster | None = None) -> bytes:
    """A PNG (its bytes) with one panel per split of `errors` (split -> one error per point): each point at
    (ms, error) with its label and the marker of its group (`groups`, one name per point, in the legend), the
    points of `fronts[split]` (a mask) joined as the Pareto front, and `reference_ms` a vertical line; with `fast`,
    the points it times again (the same path with a faster network) as hollow markers joined to their own, and
    its front."""
    ms = np.asarray(ms, dtype=np.float64)
    fast_ms = np.full_like(ms, np.nan) if fast is None else np.asarray(fast.ms, dtype=np.float64)
    timed = np.flatnonzero(np.isfinite(fast_ms))
    kinds = list(dict.fromkeys(groups))
    fig = Figure(figsize=(7.2 * len(errors), 6.2), dpi=120)
    FigureCanvasAgg(fig)
    for i, (split, error) in enumerate(errors.items()):
        error = np.asarray(error, dtype=np.float64)
        ax = fig.add_subplot(1, len(errors), i + 1)
        for k, kind in enumerate(kinds):
            mask = np.array([g == kind for g in groups])
            ax.scatter(ms[mask], error[mask], marker=MARKERS[k % len(MARKERS)], color=COLOURS[k % len(COLOURS)],
                       label=kind, zorder=3)
            again = np.intersect1d(np.flatnonzero(mask), timed)
            if len(again):
                ax.scatter(fast_ms[again], error[again], marker=MARKERS[k % len(MARKERS)], facecolors="none",
                           edgecolors=COLOURS[k % len(COLOURS)], zorder=3)
        for i in timed:     # each faster point joined to its own: the same error, less time
            ax.plot([ms[i], fast_ms[i]], [error[i], error[i]], color="gray", linewidth=0.6, zorder=1)
        if len(timed):
            ax.scatter([], [], marker="o", facecolors="none", edgecolors="black", label=fast.label)
        _front(ax, ms, error, fronts[split], "-", "Pareto front" if fast is None else f"Pareto front, {fast.first}")
        if fast is not None:
            _front(ax, np.where(np.isfinite(fast_ms), fast_ms, ms), error, fast.fronts[split], ":",
                   f"Pareto front, {fast.label}")
        if reference_ms is not None:
            ax.axvline(reference_ms, color="black", linestyle="--", linewidth=1, label=reference_label)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("ms per frame (learned: low-res sim + Loop subdivision + network; high-res: its solve)")
        ax.set_ylabel(unit)
        ax.set_title(f"{split} frames")
        ax.grid(True, which="both", alpha=0.3)
        ax.autoscale_view()
    # One legend under the panels, clear of the points.
    handles, names = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    # The labels once the panels have their final size, kept inside them (placed before the layout, boxes apart
    # in a larger panel overlapped in the final one, and the layout made room for labels past a panel's edge).
    to_points = 72.0 / fig.dpi
    for ax, error in zip(fig.axes, errors.values()):
        error = np.asarray(error, dtype=np.float64)
        anchors = ax.transData.transform(np.column_stack([ms, error])) * to_points
        unlabelled = ax.transData.transform(np.column_stack([fast_ms[timed], error[timed]])) * to_points
        bounds = tuple(np.asarray(ax.bbox.extents) * to_points)
        for label, (x, y), offset in zip(labels, zip(ms, error),
                                         place_labels(anchors, labels, bounds=bounds, unlabelled=unlabelled)):
            far = label_gap(offset, label) > LEADER_GAP
            ax.annotate(label, (x, y), textcoords="offset points", xytext=offset, fontsize=LABEL_SIZE,
                        arrowprops=LEADER if far else None)
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()


def _front(ax, ms: np.ndarray, error: np.ndarray, on_front: np.ndarray, style: str, label: str) -> None:
    """The points of mask `on_front` joined as a staircase: the least error for a budget of ms."""
    on_front = np.flatnonzero(on_front)
    order = on_front[np.argsort(ms[on_front])]
    ax.step(ms[order], error[order], where="post", color="tab:red", linestyle=style, linewidth=1.5, label=label,
            zorder=2)


def place_labels(anchors: np.ndarray, labels: list[str], size: float = LABEL_SIZE,
                 bounds: tuple[float, float, float, float] | None = None,
                 unlabelled: np.ndarray | None = None) -> list[tuple[float, float]]:
    """An offset (points) per label from its anchor (N, 2), in points: the first of LABEL_OFFSETS, then the same
    heights left of the point, whose box (text width estimated from its length) meets no box placed before it and
    no other point's marker, and lies within `bounds` (x0, y0, x1, y1: the panel, in points) if given; so that
    points at nearly the same place (networks of two widths at one budget) keep readable labels and a point at a
    panel's edge keeps its label inside; `unlabelled` (M, 2): markers without a label, kept clear too. If none is
    free, the first within bounds (else the first)."""
    markers = [(x - MARKER_HALF, y - MARKER_HALF, x + MARKER_HALF, y + MARKER_HALF) for x, y in anchors]
    others = [] if unlabelled is None else [(x - MARKER_HALF, y - MARKER_HALF, x + MARKER_HALF, y + MARKER_HALF)
                                            for x, y in unlabelled]
    placed: list[tuple[float, float, float, float]] = []
    offsets = []
    for i, ((x, y), label) in enumerate(zip(anchors, labels)):
        width = label_box((0.0, 0.0), label, size)[2]
        candidates = [*LABEL_OFFSETS, *((-dx - width, dy) for dx, dy in LABEL_OFFSETS)]
        boxes = [tuple(np.add(label_box(offset, label, size), (x, y, x, y))) for offset in candidates]
        inside = [bounds is None or (b[0] >= bounds[0] and b[1] >= bounds[1] and b[2] <= bounds[2]
                                     and b[3] <= bounds[3]) for b in boxes]
        obstacles = placed + markers[:i] + markers[i + 1:] + others
        free = [k for k, box in enumerate(boxes) if inside[k] and not any(_overlap(box, b) for b in obstacles)]
        k = free[0] if free else next((k for k, ok in enumerate(inside) if ok), 0)
        placed.append(boxes[k])
        offsets.append(candidates[k])
    return offsets


def label_box(offset: tuple[float, float], label: str, size: float = LABEL_SIZE) -> tuple[float, float, float, float]:
    """A label's box (x0, y0, x1, y1) relative to its point, in points: its width estimated from its length."""
    return offset[0], offset[1], offset[0] + 0.6 * size * len(label), offset[1] + size + 1.0


def label_gap(offset: tuple[float, float], label: str, size: float = LABEL_SIZE) -> float:
    """How far (points) a label's box at `offset` is from its point."""
    x0, y0, x1, y1 = label_box(offset, label, size)
    return float(np.hypot(max(x0, 0.0, -x1), max(y0, 0.0, -y1)))


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
