"""The study stage: the grid of (training sequences, input variant) evaluations gathered into one table, plot and
report, checked against the errors written; and clear errors for a grid with holes or a point without held-out
frames."""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from experiments.study import stage as study
from pipeline.artifacts.evaluation import Evaluation, write_evaluation
from pipeline.core import cli


def _evaluation(path: Path, network: dict[str, float], predictor: dict[str, float], parameters: int = 10) -> Path:
    def errors(l1: dict[str, float]) -> dict:
        return {split: {"l1": value, "l2": 2 * value, "normal": 0.0, "total": value} for split, value in l1.items()}
    empty = np.zeros(1)
    write_evaluation(path, {}, Evaluation({"network": errors(network), "predictor": errors(predictor)},
                                          {"network": {"l1": empty}, "predictor": {"l1": empty}},
                                          np.zeros((1, 3, 3)), np.ones(2), np.arange(2), "cpu", 1, parameters))
    return path


def test_the_grid_becomes_a_table_plot_and_report(tmp_path, capsys):
    truth = {(n, v): {"test": 1.0 / n + k, "held_out": 2.0 / n + k} for n in (1, 4) for k, v in enumerate(("a", "b"))}
    points = []
    for k, ((n, variant), l1) in enumerate(truth.items()):
        path = _evaluation(tmp_path / f"{n}_{variant}.h5", {s: e * 1e-3 for s, e in l1.items()},
                           {"test": 3e-3, "held_out": 4e-3}, parameters=1000 + k)
        points += ["--point", str(n), variant, str(path)]
    out = tmp_path / "study"
    cli.run(study.main, [str(out / "study.h5"), str(out / "study.png"), str(out / "report.md"), *points])
    with h5py.File(out / "study.h5") as f:
        assert f["counts"][()].tolist() == [1, 4] and [v.decode() for v in f["variants"][()]] == ["a", "b"]
        held = f["l1/network/held_out"][()] / 1e-3
        np.testing.assert_allclose(held, [[2.0, 0.5], [3.0, 1.5]])
        np.testing.assert_allclose(f["l1/predictor/test"][()], 3e-3)
    report = (out / "report.md").read_text()
    assert "| `a` | 2.000 (2.00x) | 0.500 (8.00x) |" in report          # held-out: 4 / 2 and 4 / 0.5
    assert "| Loop subdivision alone | 4.000 | 4.000 |" in report
    assert "`a` 1,002 parameters, `b` 1,003 parameters" in report    # the last point of each variant
    assert (out / "study.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_holes_in_the_grid_and_points_without_held_out_frames_are_refused(tmp_path, capsys):
    one = _evaluation(tmp_path / "one.h5", {"test": 1e-3, "held_out": 2e-3}, {"test": 3e-3, "held_out": 4e-3})
    no_held = _evaluation(tmp_path / "two.h5", {"test": 1e-3}, {"test": 3e-3})
    outputs = [str(tmp_path / name) for name in ("s.h5", "s.png", "r.md")]
    cases = [(["--point", "1", "a", str(one), "--point", "2", "b", str(one)], "do not fill the grid"),
             (["--point", "1", "a", str(no_held)], "no held_out errors"),
             (["--point", "0", "a", str(one)], "N must be a positive integer"),
             (["--point", "1", "a;rm", str(one)], "VARIANT letters"),
             (["--point", "1", "a", str(tmp_path / "r.md")], "same file")]
    for points, message in cases:
        with pytest.raises(SystemExit):
            cli.run(study.main, [*outputs, *points])
        assert message in capsys.readouterr().err
        assert not any(Path(p).exists() for p in outputs)
