"""tools/compare_results.py (issue 41 item 15): two clean runs compare equal although their reports and eval.h5
quote different timings, and a changed result is still found, in a report line or an array."""
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

TOOL = Path(__file__).resolve().parents[2] / "tools" / "compare_results.py"


def _run(root: Path, ms: float, l1: float, table_row: str) -> Path:
    (root / "logs").mkdir(parents=True)
    (root / "logs" / "train.log").write_text(f"took {ms} s\n")             # a run record: never compared
    report = f"# Evaluation\n\n| timing | {ms:.2f} ms per frame |\n| held-out | {table_row} |\n"
    (root / "report.md").write_text(report)
    (root / "report.html").write_text(f"<p>{ms:.2f} ms per frame</p>\n<p>{table_row}</p>\n")
    with h5py.File(root / "eval.h5", "w") as f:
        f["inference_ms"] = np.full(3, ms)
        f["errors/network/held_out/l1"] = np.float64(l1)
        f.attrs["inference_ms_median"] = ms
    return root


def _compare(a: Path, b: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(TOOL), str(a), str(b)], capture_output=True, text=True)


def test_timings_are_ignored_and_results_are_not(tmp_path):
    old = _run(tmp_path / "old", 3.25, 1.0e-3, "1.050 (1.28x)")
    same = _run(tmp_path / "same", 7.5, 1.0e-3, "1.050 (1.28x)")
    run = _compare(old, same)
    assert run.returncode == 0 and "0 differences" in run.stdout, run.stdout
    changed = _run(tmp_path / "changed", 7.5, 1.1e-3, "1.060 (1.26x)")
    run = _compare(old, changed)
    assert run.returncode == 1
    assert "report.md:4: differs" in run.stdout and "report.html:2: differs" in run.stdout
    assert "eval.h5" in run.stdout and "held_out/l1" in run.stdout
