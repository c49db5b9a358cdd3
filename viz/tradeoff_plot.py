"""The speed-accuracy figure: error against ms per frame of the learned path (log-log), every configuration a
labelled point and the Pareto front drawn, so that a person sees at a glance which one to pick for a budget."""
from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def tradeoff_plot(labels: list[str], ms: np.ndarray, errors: dict[str, np.ndarray], fronts: dict[str, np.ndarray],
                  unit: str = "L1 (x 1e-3 scene units)") -> bytes:
    """A PNG (its bytes) with one panel per split of `errors` (split -> one error per point): each point at
    (ms, error) with its label, the points of `fronts[split]` (a mask) joined as the Pareto front."""
    ms = np.asarray(ms, dtype=np.float64)
    fig = Figure(figsize=(6.4 * len(errors), 5.0), dpi=120)
    FigureCanvasAgg(fig)
    for i, (split, error) in enumerate(errors.items()):
        ax = fig.add_subplot(1, len(errors), i + 1)
        ax.scatter(ms, error, color="tab:blue", zorder=3)
        for label, x, y in zip(labels, ms, error):
            ax.annotate(label, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8)
        on_front = np.flatnonzero(fronts[split])
        order = on_front[np.argsort(ms[on_front])]
        ax.step(ms[order], np.asarray(error)[order], where="post", color="tab:red", linewidth=1.5,
                label="Pareto front", zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("learned path, ms per frame (low-res sim + Loop subdivision + network)")
        ax.set_ylabel(unit)
        ax.set_title(f"{split} frames")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=9)
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()
