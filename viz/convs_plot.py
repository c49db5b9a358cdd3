"""The operator comparison's bar chart: per task one row of two panels, per row of the table (an architecture at
one filter length) a group of bars, one per operator, at its mean error over the seeds with the lowest-to-highest
seed as an error bar. Left, the error itself with the predictor alone dashed (how much any network gains); right,
each operator's error above the group's lowest mean, in percent: the operators differ by a few percent, which the
left panel's full scale cannot show, so whether one is lower and by more than the seeds' spread is read there."""
from __future__ import annotations

import io
import textwrap
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

COLOURS = {"RC": "tab:blue", "EC": "tab:green", "SP": "tab:orange", "SPD": "tab:red"}


def _label(group: str) -> str:
    """A group's label wrapped to the width of its bars (architecture strings run to 40 characters)."""
    return "\n".join(textwrap.fill(line, 22) for line in group.split("\n"))


def _bars(ax, groups: list[str], errors: dict[str, np.ndarray]) -> None:
    width, at = 0.8 / len(errors), np.arange(len(groups))
    for k, (kind, values) in enumerate(errors.items()):
        mean = values.mean(axis=1)
        spread = np.stack([mean - values.min(axis=1), values.max(axis=1) - mean])
        ax.bar(at + (k - (len(errors) - 1) / 2) * width, mean, width, yerr=spread, capsize=3, label=kind,
               color=COLOURS.get(kind, f"C{k}"))
    ax.set_xticks(at, [_label(group) for group in groups], fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)


def convs_plot(panels: Sequence[tuple[str, list[str], dict[str, np.ndarray], float]],
               unit: str = "L1 (x 1e-3 scene units)") -> bytes:
    """A PNG (its bytes): each panel is (title, group labels, operator -> (groups, seeds) errors, the predictor's
    error), drawn as the error and as the percent above each group's lowest mean operator."""
    most = max(len(groups) for _, groups, _, _ in panels)
    fig = Figure(figsize=(2 * max(6.0, 1.5 * most + 2.0), 4.6 * len(panels)), dpi=110)
    FigureCanvasAgg(fig)
    for i, (title, groups, errors, predictor) in enumerate(panels):
        errors = {kind: np.asarray(values, dtype=np.float64) for kind, values in errors.items()}
        ax = fig.add_subplot(len(panels), 2, 2 * i + 1)
        _bars(ax, groups, errors)
        ax.axhline(predictor, linestyle="--", color="black", linewidth=1.2, label="predictor alone")
        top = max([predictor, *(np.max(values) for values in errors.values())])
        ax.set_ylim(0, 1.3 * top)          # room above the bars for the legend
        ax.set_ylabel(unit)
        ax.set_title(title)
        ax.legend(fontsize=8, ncols=len(errors) + 1)
        best = np.min([values.mean(axis=1) for values in errors.values()], axis=0)    # (groups,)
        above = fig.add_subplot(len(panels), 2, 2 * i + 2)
        _bars(above, groups, {kind: 100.0 * (values / best[:, None] - 1.0) for kind, values in errors.items()})
        above.set_ylabel("% above the group's lowest mean")
        above.set_title(f"{title}: operators against each other")
        above.legend(fontsize=8, ncols=len(errors))
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()
