"""The study stage: the grid of (point, input variant) evaluations gathered into one table, plot and report,
checked against the errors and frames written; and clear errors for a grid with holes, a bad label or a point
without held-out frames."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from experiments.study import stage as study
from pipeline.artifacts.evaluation import Evaluation, write_evaluation
from pipeline.core import cli


def _evaluation(path: Path, network: dict[str, float], predictor: dict[str, float], parameters: int = 10,
                frames: int = 100) -> Path:
    def errors(l1: dict[str, float]) -> dict:
        return {split: {"l1": value, "l2": 2 * value, "normal": 0.0, "total": value} for split, value in l1.items()}
    empty = np.zeros(1)
    write_evaluation(path, {}, Evaluation({"network": errors(network), "predictor": errors(predictor)},
                                          {"network": {"l1": empty}, "predictor": {"l1": empty}},
                                          np.zeros((1, 3, 3)), np.ones(2), np.arange(2), "cpu", 1, parameters,
                                          frames))
    return path


def test_the_grid_becomes_a_table_plot_and_report_ordered_by_kind_then_frames(tmp_path, capsys):
    # Given out of order: the oracle, 10k frames of the scene's data, 4 then 1 sequences.
    frames = {"oracle": 130_000, "f10000": 9_800, "n4": 800, "n1": 200}
    truth = {(label, v): {"test": 1.0 / frames[label] * 1e3 + k, "held_out": 2.0 / frames[label] * 1e3 + k}
             for label in frames for k, v in enumerate(("a", "b"))}
    points = []
    for k, ((label, variant), l1) in enumerate(truth.items()):
        path = _evaluation(tmp_path / f"{label}_{variant}.h5", {s: e * 1e-3 for s, e in l1.items()},
                           {"test": 3e-3, "held_out": 4e-3}, parameters=1000 + k, frames=frames[label])
        points += ["--point", label, variant, str(path)]
    out = tmp_path / "study"
    cli.run(study.main, [str(out / "study.h5"), str(out / "study.png"), str(out / "report.md"), *points])
    order = ["n1", "n4", "f10000", "oracle"]
    with h5py.File(out / "study.h5") as f:
        assert [v.decode() for v in f["labels"][()]] == order and [v.decode() for v in f["variants"][()]] == ["a", "b"]
        assert f["trained_frames"][()].tolist() == [[frames[label] for label in order]] * 2
        held = f["l1/network/held_out"][()] / 1e-3
        np.testing.assert_allclose(held, [[truth[(label, v)]["held_out"] for label in order] for v in ("a", "b")])
        np.testing.assert_allclose(f["l1/predictor/test"][()], 3e-3)
    report = (out / "report.md").read_text()
    assert "| inputs | 1 seq., 200 frames | 4 seq., 800 frames | ≤ 10,000 frames, 9,800 frames | oracle, 130,000 " \
           "frames |" in report
    assert "| `a` | 10.000 (0.40x) | 2.500 (1.60x) |" in report           # held-out: 4 / 10 and 4 / 2.5
    assert "| Loop subdivision alone | 4.000 | 4.000 | 4.000 | 4.000 |" in report
    assert "`a` 1,006 parameters, `b` 1,007 parameters" in report    # the last point of each variant
    assert (out / "study.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_holes_in_the_grid_bad_labels_and_points_without_held_out_frames_are_refused(tmp_path, capsys):
    one = _evaluation(tmp_path / "one.h5", {"test": 1e-3, "held_out": 2e-3}, {"test": 3e-3, "held_out": 4e-3})
    no_held = _evaluation(tmp_path / "two.h5", {"test": 1e-3}, {"test": 3e-3})
    outputs = [str(tmp_path / name) for name in ("s.h5", "s.png", "r.md")]
    cases = [(["--point", "n1", "a", str(one), "--point", "n2", "b", str(one)], "do not fill the grid"),
             (["--point", "n1", "a", str(no_held)], "no held_out errors"),
             (["--point", "n0", "a", str(one)], "LABEL must be n<N>, f<N>"),
             (["--point", "1", "a", str(one)], "LABEL must be n<N>, f<N>"),
             (["--point", "oracle\n", "a", str(one)], "LABEL must be n<N>, f<N>"),
             (["--point", "n1", "a;rm", str(one)], "VARIANT letters"),
             (["--point", "n1", "a", str(tmp_path / "r.md")], "same file")]
    for points, message in cases:
        with pytest.raises(SystemExit):
            cli.run(study.main, [*outputs, *points])
        assert message in capsys.readouterr().err
        assert not any(Path(p).exists() for p in outputs)
