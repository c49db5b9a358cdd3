"""What the tests of every folder share. pytest's default ("prepend") imports put this folder on sys.path when
they load this file, as they put each test folder there for its own modules: the tests import the helper modules
here (workflow_runs.py, stage_inputs.py) by bare name, as they import their own folder's (tests/hostile/hostile.py).

The tiny pants (workflow_runs.tiny_pants) built once per session, in one Snakemake run, for every test that builds
on them: `results/pants/` (the garment scene's own test reads this run) and the targets the selected tests name
with `@pytest.mark.tiny_pants_target(TARGET, **blocks)`, each with its block of the scene's config (`study`,
`tradeoff`: workflow-only settings, so they change none of the scene's jobs). One run lets the study's and the
trade-off's jobs fill the cores while the scene's chain of jobs waits on its last ones. Under pytest-xdist the
workers share that one build (a file lock in the session's shared temporary folder): two builds side by side on
CI's two cores each took twice as long as one."""
from __future__ import annotations

import fcntl
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from workflow_runs import build, tiny_pants

SCENE_TARGET = "results/pants/"
# The longest chain of jobs, when the trade-off is asked for (its re-simulation, dataset, matched training and
# evaluation, then the table): started first, with the study's jobs filling the other core around it.
FIRST = {"results/pants/tradeoff/": "results/pants/tradeoff/tradeoff.h5"}


@dataclass(frozen=True)
class TinyPants:
    workdir: Path                          # the Snakemake working directory: results/pants/ in it
    config: Path                           # the config file it was built with (tiny_pants, shard 2, the blocks)
    targets: tuple[str, ...]               # what the run built: SCENE_TARGET and the selected tests' targets
    run: subprocess.CompletedProcess       # the run, in a folder that held nothing before


@pytest.fixture(scope="session")
def tiny_pants_build(request, tmp_path_factory) -> TinyPants:
    """tiny_pants with two training sequences simulated as one batch (`shard: 2`) and the held-out walk:
    `results/pants/` and the targets of the selected tests' `tiny_pants_target` marks, built by one run that
    goes on past a failed job (`--keep-going`), returned as it ended: each test checks it. Under pytest-xdist
    the first worker to need it builds it; the others wait on the lock, then read its record (every worker
    collects the same tests, so the same marks)."""
    if not hasattr(request.config, "workerinput"):         # no xdist, or its controller
        return _build_tiny_pants(request, tmp_path_factory.mktemp("tiny_pants"))
    shared = tmp_path_factory.getbasetemp().parent
    record = shared / "tiny_pants.json"
    with open(shared / "tiny_pants.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)           # released when the file closes, or if this worker dies
        if record.exists():
            saved = json.loads(record.read_text())
            return TinyPants(Path(saved["workdir"]), Path(saved["config"]), tuple(saved["targets"]),
                             subprocess.CompletedProcess(**saved["run"]))
        built = _build_tiny_pants(request, shared / "tiny_pants")
        run = built.run
        # Written whole after the build, under the lock: a worker that finds the record finds a finished build.
        record.write_text(json.dumps({"workdir": str(built.workdir), "config": str(built.config),
                                      "targets": list(built.targets),
                                      "run": {"args": run.args, "returncode": run.returncode,
                                              "stdout": run.stdout, "stderr": run.stderr}}))
        return built


def _build_tiny_pants(request, workdir: Path) -> TinyPants:
    marks = [mark for item in request.session.items for mark in item.iter_markers("tiny_pants_target")]
    workdir.mkdir(parents=True, exist_ok=True)
    config = tiny_pants(workdir, shard=2)
    overlay = yaml.safe_load(config.read_text())
    pants = overlay["profiles"]["cpu"]["scenes"]["pants"]
    for mark in marks:
        for key, block in mark.kwargs.items():
            assert pants.setdefault(key, block) == block, f"tiny_pants_target marks disagree on {key}"
    config.write_text(yaml.safe_dump(overlay))
    targets = tuple(dict.fromkeys([SCENE_TARGET, *(mark.args[0] for mark in marks)]))
    first = [FIRST[target] for target in targets if target in FIRST]
    run = build(workdir, *targets, "--configfile", str(config), "--keep-going",
                *(("--prioritize", *first) if first else ()))
    return TinyPants(workdir, config, targets, run)
