"""Report plots: what they draw (read back from the figure) and the file bytes they become."""
from __future__ import annotations

import numpy as np
import pytest

from viz.plots import error_over_time, figure_bytes, training_curve


def test_training_curve_is_log_scaled_and_skips_missing_test_epochs():
    train = np.array([1.0, 0.5, 0.2, 0.1])
    test = np.array([np.nan, 0.6, np.nan, 0.15])
    ax = training_curve(train, test).axes[0]
    assert ax.get_yscale() == "log" and ax.get_xlabel() == "epoch"
    (train_line, test_line) = ax.get_lines()
    np.testing.assert_array_equal(train_line.get_xdata(), [1, 2, 3, 4])
    np.testing.assert_array_equal(test_line.get_xdata(), [2, 4])
    np.testing.assert_array_equal(test_line.get_ydata(), [0.6, 0.15])
    with pytest.raises(ValueError):
        training_curve(train, test[:3])


def test_error_over_time_rows_per_split_and_breaks_at_sequence_starts():
    network = np.arange(20.0)
    predictor = 2 * network
    fig = error_over_time(network, predictor, {"test": np.array([7, 1, 3, 12, 13]), "held_out": np.arange(15, 20),
                                               "train_only": np.array([], int)},
                          sequence_starts=[(0, "dance"), (10, "walk"), (15, "karate")], error_label="L2")
    test_ax, held_ax = fig.axes                                        # an empty split gets no row
    assert test_ax.get_title(loc="left") == "test" and held_ax.get_title(loc="left") == "held-out"
    loop, net = test_ax.get_lines()[:2]
    # Frames 1, 3, 7 (dance) | 12, 13 (walk): joined within a clip, broken between clips.
    np.testing.assert_array_equal(net.get_xdata(), [1, 3, 7, np.nan, 12, 13])
    np.testing.assert_array_equal(net.get_ydata(), [1, 3, 7, np.nan, 12, 13])
    np.testing.assert_array_equal(loop.get_ydata(), [2, 6, 14, np.nan, 24, 26])
    assert loop.get_label() == "Loop subdivision alone" and net.get_label() == "network"
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["Loop subdivision alone", "network"]
    # Each row shows its own frames from the start of the clip holding the first, with the clips it spans.
    assert [line.get_xdata()[0] for line in test_ax.get_lines()[2:]] == [0, 10]
    assert [t.get_text() for t in test_ax.texts] == ["dance", "walk"] and test_ax.get_xlim() == (-0.5, 13.5)
    assert [t.get_text() for t in held_ax.texts] == ["karate"] and held_ax.get_xlim() == (14.5, 19.5)
    with pytest.raises(ValueError):
        error_over_time(network, predictor, {"test": np.array([25])})


def test_figure_bytes_png_and_svg():
    fig = training_curve(np.array([1.0, 0.5]))
    assert figure_bytes(fig, "png").startswith(b"\x89PNG\r\n\x1a\n")
    assert b"<svg" in figure_bytes(fig, "svg")[:1000]
    with pytest.raises(ValueError):
        figure_bytes(fig, "jpg")
