"""The shared motion-capture data (../shared/mocap beside the project) as the scene tests read it: where it is,
and a library's manifest, the test skipped with the reason where the data is absent."""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

MOCAP = Path(__file__).resolve().parents[3] / "shared" / "mocap"


def manifest(folder: str) -> list[dict]:
    """The rows of MOCAP/folder/MANIFEST.tsv; skips the test where the library is absent."""
    path = MOCAP / folder / "MANIFEST.tsv"
    if not path.exists():
        pytest.skip(f"shared mocap library not found at {path.parent}")
    with path.open(newline="") as file:
        return list(csv.DictReader(file, delimiter="\t"))
