"""Fuzz test of issue 13: a small valid artifact of each kind, spoiled by a seeded mutation (bytes flipped or
overwritten, the file truncated; NaN, an index out of range, a wrong shape or dtype, a dataset deleted, an attr
spoiled; for model.pt NaN or misshapen weights, a dropped entry, a spoiled spec), is fed to the stage that reads
it. The stage may take it (exit 0: the damage changed only numbers it accepts) or refuse it with one `error:`
line and no output; it must never crash (a signal), hang (the time limit), or end in a traceback."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from fuzzing import (BYTE_MUTATIONS, H5_FILE_MUTATIONS, H5_MUTATIONS, MODEL_MUTATIONS, WARP_DRIVER_NOTICE, Case, mutate,
                     run_cases)
from hostile import ARCH, write_patch_scene
from pipeline import train

SEED = 13
TIMEOUT = 60            # seconds per case; a valid input takes 1-3 s
# artifact: number of cases (40 in all)
CASES_PER_ARTIFACT = {"scene.h5": 7, "subdiv.h5": 7, "sim_low.h5": 6, "operators.h5": 7, "dataset.h5": 7,
                      "model.pt": 6}


def _plan() -> list[tuple[str, str, str]]:
    """(case name, artifact, mutation kind): each artifact's cases walk through the kinds from a different start,
    so that every kind meets several artifacts."""
    plan = []
    for start, (artifact, count) in enumerate(CASES_PER_ARTIFACT.items()):
        own = MODEL_MUTATIONS if artifact == "model.pt" else {**H5_FILE_MUTATIONS, **H5_MUTATIONS}
        kinds = [*BYTE_MUTATIONS, *own]
        for i in range(count):
            kind = kinds[(2 * start + i) % len(kinds)]
            plan.append((f"{artifact}-{i}-{kind}", artifact, kind))
    return plan


PLAN = _plan()


@pytest.fixture(scope="module")
def originals(valid, tmp_path_factory) -> Path:
    """The session's valid artifacts, plus the patch scene's settings.json and scene.h5 and a model trained for
    one epoch on the valid dataset."""
    folder = tmp_path_factory.mktemp("originals")
    for name in ("subdiv.h5", "operators.h5", "dataset.h5", "sequence/sim_low.h5", "sequence/sim_high.h5"):
        (folder / name).parent.mkdir(exist_ok=True)
        shutil.copy(valid / name, folder / name)
    write_patch_scene(folder)
    train.main([str(a) for a in (folder / "dataset.h5", folder / "operators.h5", folder / "model.pt",
                                 folder / "train.h5", *ARCH, "--epochs", "1", "--quiet")])
    return folder


def _command(artifact: str, spoiled: Path, originals: Path, out: Path) -> tuple[str, list]:
    """The stage that reads `artifact`, and its arguments with the spoiled copy in place of the original."""
    if artifact == "scene.h5":
        return "simulate", ["low", originals / "settings.json", spoiled, out / "sim_low.h5", "--quiet"]
    if artifact in ("subdiv.h5", "sim_low.h5"):
        subdiv = spoiled if artifact == "subdiv.h5" else originals / "subdiv.h5"
        sequence = spoiled.parent if artifact == "sim_low.h5" else originals / "sequence"
        return "dataset", [subdiv, out / "dataset.h5", sequence, "--quiet"]
    if artifact in ("operators.h5", "dataset.h5"):
        inputs = {"dataset.h5": originals / "dataset.h5", "operators.h5": originals / "operators.h5", artifact: spoiled}
        return "train", [inputs["dataset.h5"], inputs["operators.h5"], out / "model.pt", out / "train.h5", *ARCH,
                         "--epochs", "1", "--threads", "1", "--quiet"]
    return "evaluate", [originals / "dataset.h5", originals / "operators.h5", spoiled, out / "eval.h5",
                        out / "report.md", "--render-frames", "0", "--video-frames", "0", "--export-frames", "1",
                        "--timing-frames", "1", "--threads", "1", "--quiet"]


@pytest.fixture(scope="module")
def fuzzed(originals, tmp_path_factory) -> dict[str, tuple[Case, str, object]]:
    """Every case of the plan run: name -> (case, what the mutation did, outcome)."""
    root = tmp_path_factory.mktemp("fuzz")
    cases, done = [], {}
    for index, (name, artifact, kind) in enumerate(PLAN):
        folder = root / f"case_{index:02d}"
        spoiled = folder / "in" / ("sequence/sim_low.h5" if artifact == "sim_low.h5" else artifact)
        spoiled.parent.mkdir(parents=True)
        shutil.copy(originals / ("sequence/sim_low.h5" if artifact == "sim_low.h5" else artifact), spoiled)
        if artifact == "sim_low.h5":
            shutil.copy(originals / "sequence" / "sim_high.h5", spoiled.parent)
        done[name] = mutate(spoiled, kind, np.random.default_rng([SEED, index]))
        stage, args = _command(artifact, spoiled, originals, folder / "out")
        cases.append(Case(name, stage, [str(a) for a in args], folder / "out", folder / "stderr.txt"))
    outcomes = run_cases(cases, TIMEOUT)
    return {case.name: (case, done[case.name], outcomes[case.name]) for case in cases}


@pytest.mark.parametrize("name", [name for name, _, _ in PLAN])
def test_a_spoiled_artifact_is_taken_or_refused_cleanly(fuzzed, name):
    case, mutation, outcome = fuzzed[name]
    told = (f"{name} ({mutation}): python -m pipeline.{case.stage} {' '.join(case.argv)}\nexit {outcome.exitcode} "
            f"after {outcome.seconds:.1f} s; stderr:\n{outcome.stderr[-3000:]}")
    assert outcome.exitcode is not None, f"hung: {told}"
    assert outcome.exitcode in (0, 2), f"crashed: {told}"
    assert "Traceback" not in outcome.stderr, told
    if outcome.exitcode == 2:
        lines = [line for line in outcome.stderr.splitlines() if not line.startswith(WARP_DRIVER_NOTICE)]
        assert len(lines) == 1 and lines[0].startswith("error: "), told
        left = [p for p in case.out.rglob("*") if p.is_file()] if case.out.exists() else []
        assert left == [], f"left {left}: {told}"


def test_the_plan_covers_every_mutation_and_artifact():
    kinds = {kind for _, _, kind in PLAN}
    assert kinds == {*BYTE_MUTATIONS, *H5_FILE_MUTATIONS, *H5_MUTATIONS, *MODEL_MUTATIONS}
    assert {artifact for _, artifact, _ in PLAN} == set(CASES_PER_ARTIFACT) and len(PLAN) == 40
