"""The generalisation study's figure: error on the held-out motion (and on test frames of the trained motions)
against the number of training sequences, one line per input variant, Loop subdivision alone as the floor."""
from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

TITLES = {"held_out": "held-out motion (never trained on)", "test": "test frames of the trained motions"}


def study_plot(counts: list[int], variants: list[str], network: dict[str, np.ndarray],
               predictor: dict[str, np.ndarray], unit: str = "L1 (x 1e-3 scene units)") -> bytes:
    """A PNG (its bytes, for the caller to write) with one panel per split (`network[split]`, `predictor[split]`: (variants, counts) errors): the
    network's error per variant against the training sequences (log x), and Loop subdivision's, dashed."""
    fig = Figure(figsize=(6.0 * len(network), 4.8), dpi=120)
    FigureCanvasAgg(fig)
    for i, split in enumerate(network):
        ax = fig.add_subplot(1, len(network), i + 1)
        for k, variant in enumerate(variants):
            ax.plot(counts, network[split][k], marker="o", linewidth=2, label=f"network, inputs: {variant}")
        floor = predictor[split].mean(axis=0)
        ax.plot(counts, floor, linestyle="--", color="black", linewidth=1.5, label="Loop subdivision alone")
        ax.set_xscale("log", base=2)
        ax.set_xticks(counts, [str(n) for n in counts])
        ax.set_xlabel("training sequences")
        ax.set_ylabel(unit)
        ax.set_ylim(bottom=0)
        ax.set_title(TITLES.get(split, split))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=9)
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()
