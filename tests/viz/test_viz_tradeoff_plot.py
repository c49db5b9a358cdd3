"""The speed-accuracy figure's labels: points at nearly one place (networks of two widths at one budget) must keep
readable, non-overlapping labels, a label placed away from its point joined to it by a line."""
from __future__ import annotations

import numpy as np

from viz.tradeoff_plot import (LABEL_OFFSETS, LABEL_SIZE, LEADER_GAP, MARKER_HALF, Faster, label_gap, place_labels,
                               tradeoff_plot)


def _box(anchor, offset, label):
    x, y = anchor[0] + offset[0], anchor[1] + offset[1]
    return x, y, x + 0.6 * LABEL_SIZE * len(label), y + LABEL_SIZE + 1.0


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def test_labels_of_coincident_points_do_not_overlap_and_lone_points_keep_the_first_place():
    labels = ["1 sub, RC9 x0.125", "1 sub, RC9 x0.25", "1 sub, RC9 x0.25 (matched)", "4 sub, Loop only"]
    anchors = np.array([[100.0, 200.0], [101.0, 200.5], [100.5, 199.0], [400.0, 50.0]])
    offsets = place_labels(anchors, labels)
    boxes = [_box(a, o, lab) for a, o, lab in zip(anchors, offsets, labels)]
    assert not any(_overlap(boxes[i], boxes[j]) for i in range(3) for j in range(i + 1, 3))
    assert offsets[0] == LABEL_OFFSETS[0] and offsets[3] == LABEL_OFFSETS[0]
    assert len(set(offsets[:3])) == 3


def test_a_cluster_of_a_budgets_points_gets_disjoint_labels_and_the_far_ones_a_leader_line():
    """Ten points within a marker of each other (every network and Loop subdivision at 8 substeps): each label a
    box of its own, off the other points' markers; the ones not beside their point are joined to it."""
    labels = [f"8 sub, RC{9 + k % 5} x/{2 ** (k % 3)}" for k in range(10)]
    anchors = np.array([[200.0 + k % 3, 150.0 + k % 4] for k in range(10)])
    offsets = place_labels(anchors, labels)
    boxes = [_box(a, o, lab) for a, o, lab in zip(anchors, offsets, labels)]
    assert not any(_overlap(boxes[i], boxes[j]) for i in range(10) for j in range(i + 1, 10))
    gaps = [label_gap(offset, label) for offset, label in zip(offsets, labels)]
    assert gaps[0] < LEADER_GAP and sum(gap > LEADER_GAP for gap in gaps) >= 6
    # beside its point: the first two places, above or below it on the right; a place three lines up is not
    assert label_gap(LABEL_OFFSETS[1], labels[0]) < LEADER_GAP < label_gap(LABEL_OFFSETS[2], labels[0])
    left = (-LABEL_OFFSETS[0][0] - _box((0, 0), (0, 0), labels[0])[2], LABEL_OFFSETS[0][1])
    assert label_gap(left, labels[0]) < LEADER_GAP


def test_a_label_stays_inside_its_panel_and_off_the_other_points():
    """A point at the panel's right edge gets its label on its left; a label whose first place would cover
    another point's marker goes elsewhere."""
    bounds = (0.0, 0.0, 300.0, 300.0)
    labels = ["high-res 8x75, every iteration", "1 sub, Loop only", "a neighbour"]
    anchors = np.array([[290.0, 100.0], [50.0, 50.0], [60.0, 58.0]])     # the third's marker where the second's
    offsets = place_labels(anchors, labels, bounds=bounds)                 # first label box would be
    boxes = [_box(a, o, lab) for a, o, lab in zip(anchors, offsets, labels)]
    assert offsets[0][0] < 0 and boxes[0][0] >= 0 and boxes[0][2] <= 290.0
    for i, box in enumerate(boxes):
        assert bounds[0] <= box[0] and box[2] <= bounds[2] and bounds[1] <= box[1] and box[3] <= bounds[3]
        markers = [(x - MARKER_HALF, y - MARKER_HALF, x + MARKER_HALF, y + MARKER_HALF)
                   for j, (x, y) in enumerate(anchors) if j != i]
        assert not any(_overlap(box, marker) for marker in markers)
    assert offsets[1] != LABEL_OFFSETS[0]


def test_the_figure_is_a_png_with_coincident_points():
    png = tradeoff_plot(["a", "b", "c"], np.array([10.0, 10.0, 100.0]),
                        {"test": np.array([1.0, 1.0, 0.5]), "held-out": np.array([2.0, 2.0, 1.0])},
                        {"test": np.array([True, False, True]), "held-out": np.array([True, False, True])},
                        ["learned", "learned", "high-res"], reference_ms=300.0)
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 10_000


def test_labels_keep_clear_of_the_unlabelled_markers_of_the_faster_timing():
    """A hollow marker (the same path timed with the fused network) where a label's first place would be sends
    the label elsewhere; without it the label takes the first place."""
    labels, anchors = ["1 sub, RC9 x0.25"], np.array([[100.0, 100.0]])
    first = _box(anchors[0], LABEL_OFFSETS[0], labels[0])
    hollow = np.array([[(first[0] + first[2]) / 2, (first[1] + first[3]) / 2]])
    assert place_labels(anchors, labels) == [LABEL_OFFSETS[0]]
    offset = place_labels(anchors, labels, unlabelled=hollow)[0]
    box = _box(anchors[0], offset, labels[0])
    marker = (hollow[0, 0] - MARKER_HALF, hollow[0, 1] - MARKER_HALF, hollow[0, 0] + MARKER_HALF,
              hollow[0, 1] + MARKER_HALF)
    assert offset != LABEL_OFFSETS[0] and not _overlap(box, marker)


def test_the_figure_with_a_faster_timing_differs_from_the_figure_without():
    ms, errors = np.array([10.0, 4.0]), {"test": np.array([1.0, 2.0])}
    fronts, groups = {"test": np.array([True, True])}, ["learned", "Loop"]
    plain = tradeoff_plot(["a", "b"], ms, errors, fronts, groups)
    fast = Faster(np.array([3.0, np.nan]), {"test": np.array([True, False])}, "fused", "fp32")
    both = tradeoff_plot(["a", "b"], ms, errors, fronts, groups, fast=fast)
    assert both.startswith(b"\x89PNG\r\n\x1a\n") and both != plain
