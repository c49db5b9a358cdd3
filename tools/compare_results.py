"""Compare two results/<scene>/ folders artifact by artifact: the check that a refactor changed no output.

    python tools/compare_results.py OLD_DIR NEW_DIR

HDF5 files: every dataset (dtype, shape, values bit for bit, NaN equal to NaN) and every attr. model.pt: every
entry, tensors bit for bit. Reports (report.md, report.html) line by line, but for lines quoting the timings below.
Every other file byte for byte. Wall-clock measurements (solve and inference times, training seconds) and the
package-version attr differ between any two runs and are listed, not compared.
Exit status 1 and one line per difference if anything else differs.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import h5py
import numpy as np

# Wall-clock figures: datasets and attrs that measure time, not results.
TIMINGS = {"solve_ms", "setup_seconds", "inference_ms", "inference_ms_fused", "epoch/seconds", "wall_seconds",
           "inference_ms_median", "phase_seconds"}
PROVENANCE = {"versions"}
# Report lines (report.md, and the same paragraph in report.html) quoting the timings above.
TIMED_REPORT_WORDS = ("ms per frame", "min ")
# Files that record a run rather than its results (Snakemake's per-rule logs and benchmarks).
RUN_RECORDS = ("logs", "benchmarks")


def compare_h5(old: Path, new: Path) -> list[str]:
    problems = []
    with h5py.File(old, "r") as a, h5py.File(new, "r") as b:
        names_a, names_b = _walk(a), _walk(b)
        for name in sorted(set(names_a) ^ set(names_b)):
            problems.append(f"{new}: '{name}' only in {'old' if name in names_a else 'new'}")
        for name in sorted(set(names_a) & set(names_b)):
            obj_a, obj_b = a[name] if name else a, b[name] if name else b
            problems += _compare_attrs(new, name, obj_a.attrs, obj_b.attrs)
            if isinstance(obj_a, h5py.Dataset) and name.split("/")[-1] not in TIMINGS and name not in TIMINGS:
                problems += _compare_arrays(new, name, obj_a[()], obj_b[()])
    return problems


def _walk(f: h5py.File) -> list[str]:
    names = [""]
    f.visit(names.append)
    return names


def _compare_attrs(path: Path, name: str, attrs_a, attrs_b) -> list[str]:
    problems = []
    for key in sorted(set(attrs_a) | set(attrs_b)):
        if key in TIMINGS or key in PROVENANCE:
            continue
        if key not in attrs_a or key not in attrs_b:
            problems.append(f"{path}: attr '{name}@{key}' only in {'old' if key in attrs_a else 'new'}")
        else:
            problems += _compare_arrays(path, f"{name}@{key}", attrs_a[key], attrs_b[key])
    return problems


def _compare_arrays(path: Path, name: str, a, b) -> list[str]:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype != b.dtype or a.shape != b.shape:
        return [f"{path}: '{name}' is {a.dtype}{a.shape} vs {b.dtype}{b.shape}"]
    equal = np.array_equal(a, b, equal_nan=a.dtype.kind in "fc")
    return [] if equal else [f"{path}: '{name}' values differ"]


def compare_model(old: Path, new: Path) -> list[str]:
    import torch

    a, b = (torch.load(p, map_location="cpu", weights_only=True) for p in (old, new))
    problems = []
    for key in sorted(set(a) | set(b)):
        if key not in a or key not in b:
            problems.append(f"{new}: entry '{key}' only in {'old' if key in a else 'new'}")
        elif key == "state_dict":
            for tensor in sorted(set(a[key]) | set(b[key])):
                if tensor not in a[key] or tensor not in b[key] or not torch.equal(a[key][tensor], b[key][tensor]):
                    problems.append(f"{new}: weights '{tensor}' differ")
        elif a[key] != b[key]:
            problems.append(f"{new}: entry '{key}' differs")
    return problems


def compare_text(old: Path, new: Path) -> list[str]:
    lines_a, lines_b = old.read_text().splitlines(), new.read_text().splitlines()
    if len(lines_a) != len(lines_b):
        return [f"{new}: {len(lines_b)} lines vs {len(lines_a)}"]
    return [f"{new}:{i + 1}: differs" for i, (x, y) in enumerate(zip(lines_a, lines_b))
            if x != y and not any(word in x for word in TIMED_REPORT_WORDS)]


def compare_dirs(old: Path, new: Path) -> tuple[list[str], int]:
    def files(root: Path) -> set[Path]:
        return {p.relative_to(root) for p in root.rglob("*")
                if p.is_file() and p.relative_to(root).parts[0] not in RUN_RECORDS}

    files_a, files_b = files(old), files(new)
    problems = [f"{rel}: only in {'old' if rel in files_a else 'new'}" for rel in sorted(files_a ^ files_b)]
    for rel in sorted(files_a & files_b):
        a, b = old / rel, new / rel
        if rel.suffix == ".h5":
            problems += compare_h5(a, b)
        elif rel.suffix == ".pt":
            problems += compare_model(a, b)
        elif rel.suffix in (".md", ".html"):
            problems += compare_text(a, b)
        elif a.read_bytes() != b.read_bytes():
            problems.append(f"{b}: bytes differ")
    return problems, len(files_a & files_b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args()
    problems, n_files = compare_dirs(args.old, args.new)
    for line in problems:
        print(line)
    print(f"{n_files} files compared, {len(problems)} differences (ignored: {', '.join(sorted(TIMINGS | PROVENANCE))})")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
