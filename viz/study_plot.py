"""The generalisation study's figure: error on the held-out motion (and on test frames of the trained motions)
against the frames trained on, one line per input variant and kind of point, the oracle (trained on the held-out
motion too) as a dotted level, Loop subdivision alone as the dashed floor."""
from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

TITLES = {"held_out": "held-out motion (never trained on)", "test": "test frames of the trained motions"}
KINDS = {"n": ("o", "-", "the first N sequences"), "f": ("s", "-.", "the scene's data within N frames")}


def study_plot(frames: np.ndarray, kinds: list[str], variants: list[str], network: dict[str, np.ndarray],
               predictor: dict[str, np.ndarray], unit: str = "L1 (x 1e-3 scene units)") -> bytes:
    """A PNG (its bytes, for the caller to write) with one panel per split: `network[split]` and `predictor[split]`
    are (variants, points) errors, `frames` the points' frames trained on (variants, points), `kinds` each point's
    kind (n: sequences, f: frames, o: oracle). Log x; one colour per variant."""
    fig = Figure(figsize=(6.5 * len(network), 5.0), dpi=120)
    FigureCanvasAgg(fig)
    colours = [f"C{k}" for k in range(len(variants))]
    for i, split in enumerate(network):
        ax = fig.add_subplot(1, len(network), i + 1)
        for k, variant in enumerate(variants):
            for kind, (marker, style, words) in KINDS.items():
                on = [j for j, point_kind in enumerate(kinds) if point_kind == kind]
                if on:
                    ax.plot(frames[k, on], network[split][k, on], marker=marker, linestyle=style, linewidth=2,
                            color=colours[k], label=f"{variant}: {words}")
            for j in (j for j, point_kind in enumerate(kinds) if point_kind == "o"):
                ax.axhline(network[split][k, j], linestyle=":", linewidth=1.5, color=colours[k],
                           label=f"{variant}: oracle ({frames[k, j]:,} frames, held-out ones among them)")
        order = np.argsort(frames[0])
        ax.plot(frames[0, order], predictor[split][0, order], linestyle="--", color="black", linewidth=1.5,
                label="Loop subdivision alone")
        ax.set_xscale("log")
        ax.set_xlabel("frames trained on")
        ax.set_ylabel(unit)
        ax.set_ylim(bottom=0)
        ax.set_title(TITLES.get(split, split))
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png")
    return png.getvalue()
