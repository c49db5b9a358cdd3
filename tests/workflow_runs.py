"""The Snakemake workflow run by the tests: from a folder that holds nothing of the project (`--directory`), on
CI's two cores, on tiny scenes (`tiny_pants`: pants shrunk to seconds); and what a run printed, read back (its
planned jobs, their counts, the tail of a failed run). Shared by the workflow tests of the stage chain
(tests/pipeline) and of the experiment families (tests/experiments), and by tests/conftest.py's tiny pants build.
"""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
# This interpreter's Snakemake as a module: a script beside sys.executable exists in a venv, not in every install.
SNAKEMAKE = (sys.executable, "-m", "snakemake")


def snakemake(workdir, *args):
    return subprocess.run([*SNAKEMAKE, "--cores", "2", "--snakefile", str(REPO / "Snakefile"),
                           "--directory", str(workdir), *args], capture_output=True, text=True)


# How the builds of the tiny scenes run (`build`), for time on CI's two cores; what they make is the same:
# - the rules that take every core (`threads: workflow.cores`) take one: at these sizes they are single-threaded in
#   practice (imports, renders, networks of a few thousand weights), so two run side by side;
# - the `run:` rules (settings files, links) run in Snakemake's own process instead of a new Snakemake process
#   each, which parses the Snakefile and config again (~3 s of CPU for a job of milliseconds).
# The smoke test (tests/pipeline/test_workflow.py) runs the default way.
TINY_BUILD = ("--force-use-threads", "--set-threads", *(f"{rule}=1" for rule in (
    "train", "evaluate", "study_train", "study_evaluate", "application_train", "application_evaluate",
    "multi_train", "multi_evaluate", "tradeoff_train", "tradeoff_train_matched", "tradeoff_train_matched_width",
    "tradeoff_evaluate", "tradeoff", "convs_train", "convs_evaluate")))


def build(workdir, *args):
    """`snakemake` for a build of the tiny scenes, run as TINY_BUILD says."""
    return snakemake(workdir, *args, *TINY_BUILD)


def tail(run):
    """What a failed run said: Snakemake logs on stderr, a stage's own messages come through `tee` on stdout."""
    return run.stdout[-2000:] + run.stderr[-3000:]


def planned_jobs(run) -> dict[str, dict[str, str]]:
    """The jobs of a dry run (`-n -p`): rule name -> its printed fields (log, benchmark, resources, shell...);
    for a rule with several jobs (one per sequence), those of its last."""
    jobs, current = {}, None
    for line in run.stdout.splitlines():
        if line.startswith("rule "):
            current = jobs[line[len("rule "):].rstrip(":")] = {}
        elif current is not None and line.startswith("Shell command: "):
            current["shell"] = line[len("Shell command: "):]
        elif current is not None and re.match(r"    \w+: ", line):
            key, value = line.strip().split(": ", 1)
            current[key] = value
    return jobs


TINY_FRAMES = 24


def tiny_pants(tmp_path, name="tiny.yaml", sequences=2, shard=1, **mannequin) -> Path:
    """A config file shrinking pants to seconds: `sequences` training sequences of TINY_FRAMES frames, simulated
    `shard` at a time."""
    config = yaml.safe_load((REPO / "workflow_config.yaml").read_text())
    config["profiles"]["cpu"]["scenes"]["pants"] = {
        "frames": TINY_FRAMES, "sequences": sequences, "shard": shard, "mesh": {"max_edge": 0.25},
        "drivers": {"mannequin": {"settle_frames": 3, "blend_frames": 5, **mannequin}},
        "solver": {"substeps": 2, "iterations": 10}, "high_res": {"subdivision_levels": 1},
        "training": {"epochs": 1},
        "evaluation": {"render_frames": 2, "video_frames": 2, "export_frames": 2, "timing_frames": 2}}
    path = tmp_path / name
    path.write_text(yaml.safe_dump(config))
    return path


def planned_counts(run) -> dict[str, int]:
    """Jobs per rule of a dry run, from its job-stats table."""
    table = run.stdout.split("Job stats:")[1].split("\n\n")[0]
    return {words[0]: int(words[1]) for words in map(str.split, table.splitlines()[3:]) if len(words) == 2}
