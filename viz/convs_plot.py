"""The operator comparison's bar chart: per task one panel, per row of the table (an architecture at one filter
length) a group of bars, one per operator, at its mean error over the seeds with the lowest-to-highest seed as an
error bar, and the predictor alone dashed: whether one operator is lower, and by more than the seeds' spread."""
from __future__ import annotations

import io
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

COLOURS = {"RC": "tab:blue", "EC": "tab:green", "SP": "tab:orange", "SPD": "tab:red"}


def convs_plot(panels: Sequence[tuple[str, list[str], dict[str, np.ndarray], float]],
               unit: str = "L1 (x 1e-3 scene units)") -> bytes:
    """A PNG (its bytes): each panel is (title, group labels, operator -> (groups, seeds) errors, the predictor's
    error); bars at the seeds' mean, error bars from the lowest to the highest seed."""
    fig = Figure(figsize=(max(6.0, 1.6 * max(len(groups) for _, groups, _, _ in panels) + 2.5), 4.2 * len(panels)),
                 dpi=110)
    FigureCanvasAgg(fig)
    for i, (title, groups, errors, predictor) in enumerate(panels):
        ax = fig.add_subplot(len(panels), 1, i + 1)
        width = 0.8 / len(errors)
        at = np.arange(len(groups))
        for k, (kind, values) in enumerate(errors.items()):
            values = np.asarray(values, dtype=np.float64)
            mean = values.mean(axis=1)
            spread = np.stack([mean - values.min(axis=1), values.max(axis=1) - mean])
            ax.bar(at + (k - (len(errors) - 1) / 2) * width, mean, width, yerr=spread, capsize=3, label=kind,
                   color=COLOURS.get(kind, f"C{k}"))
        ax.axhline(predictor, linestyle="--", color="black", linewidth=1.2, label="predictor alone")
        ax.set_xticks(at, groups, fontsize=8)
        ax.set_ylabel(unit)
        top = max([predictor, *(np.max(values) for values in errors.values())])
        ax.set_ylim(0, 1.3 * top)          # room above the bars for the legend
        ax.set_title(title)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8, ncols=len(errors) + 1)
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()
