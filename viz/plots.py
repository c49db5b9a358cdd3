"""Report plots: the training curve and the per-frame error over time (matplotlib Agg, no pyplot global state).

Each function returns a matplotlib Figure; `figure_bytes` turns it into PNG or SVG bytes, for a file written
through the caller's atomic writer or a data: URI in an HTML page.
"""
from __future__ import annotations

import io
from typing import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

NETWORK_COLOR, PREDICTOR_COLOR, BOUNDARY_COLOR = "#1f5fbf", "#d9731a", "0.55"
WIDTH, ROW_HEIGHT = 11.0, 3.6           # inches


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_bytes(fig: Figure, fmt: str = "png", dpi: int = 100) -> bytes:
    """The figure as PNG or SVG file bytes."""
    if fmt not in ("png", "svg"):
        raise ValueError(f"fmt must be 'png' or 'svg', got {fmt!r}")
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, dpi=dpi)
    return buffer.getvalue()


def training_curve(train_loss: np.ndarray, test_loss: np.ndarray | None = None,
                   title: str = "Training curve") -> Figure:
    """Loss per epoch (epoch 1 first) on a log scale: train, and test where given (NaN: an epoch without a test
    evaluation; its points are joined across the gap)."""
    train_loss = np.asarray(train_loss, dtype=np.float64)
    if train_loss.ndim != 1 or len(train_loss) == 0:
        raise ValueError("train_loss must be a non-empty 1-D array (one loss per epoch)")
    fig = _figure(WIDTH, ROW_HEIGHT + 0.6)
    ax = fig.add_subplot()
    epochs = np.arange(1, len(train_loss) + 1)
    ax.plot(epochs, train_loss, color=NETWORK_COLOR, lw=2, label="train", marker="o" if len(epochs) < 30 else None)
    if test_loss is not None:
        test_loss = np.asarray(test_loss, dtype=np.float64)
        if test_loss.shape != train_loss.shape:
            raise ValueError(f"test_loss has {test_loss.shape} entries, train_loss {train_loss.shape}")
        known = np.isfinite(test_loss)
        ax.plot(epochs[known], test_loss[known], color=PREDICTOR_COLOR, lw=2, marker="s", label="test")
    ax.set_yscale("log")
    ax.set_xlabel("epoch", fontsize=12)
    ax.set_ylabel("loss (log scale)", fontsize=12)
    ax.set_title(title, fontsize=14)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=11)
    return fig


def error_over_time(network: np.ndarray, predictor: np.ndarray, splits: Mapping[str, np.ndarray],
                    sequence_starts: Sequence[tuple[int, str]] = (), error_label: str = "error",
                    title: str = "Per-frame error", predictor_label: str = "Loop subdivision alone") -> Figure:
    """One row per split (name -> frame ids, e.g. test and held-out): the error of the network and of Loop
    subdivision alone (`network`, `predictor`: (F,) per frame of the whole sequence) against the frame number.
    `sequence_starts` ((first frame, name), e.g. each motion clip) are drawn as labelled dashed lines and break
    the lines there, so a clip change reads as one; within a sequence, frames a split skips are joined."""
    network, predictor = np.asarray(network, dtype=np.float64), np.asarray(predictor, dtype=np.float64)
    if network.ndim != 1 or network.shape != predictor.shape:
        raise ValueError(f"network and predictor must be (F,) arrays alike, got {network.shape}, {predictor.shape}")
    rows = [(name, np.sort(np.asarray(ids, dtype=np.int64))) for name, ids in splits.items() if len(ids)]
    if not rows:
        raise ValueError("error_over_time needs at least one non-empty split")
    fig = _figure(WIDTH, ROW_HEIGHT * len(rows) + 0.8)
    axes = fig.subplots(len(rows), 1, squeeze=False)[:, 0]
    starts = sorted(sequence_starts)
    for ax, (name, frames) in zip(axes, rows):
        if frames.min() < 0 or frames.max() >= len(network):
            raise ValueError(f"split {name!r} has frames outside 0..{len(network) - 1}")
        for values, label, color in ((predictor, predictor_label, PREDICTOR_COLOR),
                                     (network, "network", NETWORK_COLOR)):
            x, y = _broken_at(frames, values[frames], [start for start, _ in starts])
            ax.plot(x, y, color=color, lw=1.6, label=label, marker="." if len(frames) < 200 else None)
        # Each row spans its own frames, from the start of the sequence holding the first (so it is named).
        first = max([start for start, _ in starts if start <= frames[0]], default=frames[0])
        for start, clip in starts:
            if first <= start <= frames[-1]:
                ax.axvline(start, color=BOUNDARY_COLOR, ls="--", lw=1)
                ax.annotate(clip, (start, 1), xycoords=("data", "axes fraction"), xytext=(3, -3),
                            textcoords="offset points", va="top", fontsize=10, color="0.3")
        ax.set_xlim(first - 0.5, frames[-1] + 0.5)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("frame", fontsize=12)
        ax.set_ylabel(error_label, fontsize=12)
        ax.set_title(name.replace("_", "-"), fontsize=12, loc="left")
        ax.grid(True, alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=11)
    fig.suptitle(title, fontsize=14)
    return fig


def _broken_at(frames: np.ndarray, values: np.ndarray, starts: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """x, y with a NaN (which matplotlib draws as a break) between consecutive frames on either side of a start."""
    crossing = np.searchsorted(np.sort(starts), frames, side="right")       # sequence index of each frame
    gap = np.flatnonzero(np.diff(crossing) != 0) + 1
    return np.insert(frames.astype(np.float64), gap, np.nan), np.insert(values, gap, np.nan)
