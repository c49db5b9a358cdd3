"""The workflow through the Slurm profile (profiles/slurm) on a real Slurm: every job that is no local rule goes
through sbatch with its threads, memory, runtime and GPUs, shows in the accounting (`sacct`), and the artifacts
equal those of a local run, bit for bit (tools/compare_results.py). The training runs as two ranks under torchrun
inside its Slurm job (`training.ranks: 2`; gloo, as the machine has no GPU), as a job asking for two GPUs would.

Needs a Slurm whose controller answers, its accounting included, and the executor plugin
(requirements-cluster.txt): `make test-cluster` brings one up on this machine (tools/local_slurm.sh), runs this
with LEARNED_CLOTH_SLURM=1 and tears Slurm down. Without that variable the test is skipped: on a machine that is a
real cluster's login node, `make test` must not submit jobs to it. With it, a missing Slurm is a failure.
"""
from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys

import pytest
import torch
import yaml
from workflow_runs import REPO, snakemake, tail

PROFILE = REPO / "profiles" / "slurm"
# The jobs of the patch scene that run as Slurm jobs (one each: a grid scene has one sequence), and the rules
# that run inside Snakemake (`localrule: True`).
CLUSTER_JOBS = {"scene", "sequence", "subdivide", "simulate_low", "simulate_high", "operators", "dataset", "train",
                "evaluate"}
LOCAL_RULES = {"settings", "simulation_settings"}


def answers(*command: str) -> bool:
    """Whether a Slurm client command succeeds within 20 s (without a config it looks for a controller in DNS)."""
    try:
        return subprocess.run(command, capture_output=True, timeout=20).returncode == 0
    except subprocess.TimeoutExpired:
        return False


def slurm_missing() -> str | None:
    """Why this machine cannot run the test, or None."""
    if shutil.which("sbatch") is None or shutil.which("sacct") is None:
        return "no Slurm client (sbatch, sacct)"
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        return "no Snakemake Slurm executor plugin (pip install -r requirements-cluster.txt)"
    if not answers("scontrol", "ping"):
        return "no Slurm controller answers (tools/local_slurm.sh up)"
    if not answers("sacct", "-n", "-X", "-S", "now"):
        return "Slurm has no accounting (sacct fails)"
    return None


@pytest.fixture(scope="module", autouse=True)
def slurm():
    if not os.environ.get("LEARNED_CLOTH_SLURM"):
        pytest.skip("submits Slurm jobs: run by `make test-cluster` (LEARNED_CLOTH_SLURM=1)")
    reason = slurm_missing()
    if reason is not None:
        pytest.fail(f"LEARNED_CLOTH_SLURM is set but {reason}")


def accounted_jobs(job_ids: list[str]) -> dict[str, dict[str, str]]:
    """sacct's record of each job (its allocation, not its steps): rule (the plugin's comment), state, CPUs,
    memory asked for, time limit."""
    fields = ("JobID", "Comment", "State", "ReqCPUS", "ReqMem", "Timelimit")
    run = subprocess.run(["sacct", "-n", "-X", "-P", "-j", ",".join(job_ids), "-o", ",".join(fields)],
                         capture_output=True, text=True, check=True)
    jobs = {}
    for line in run.stdout.splitlines():
        record = dict(zip(fields, line.split("|")))
        jobs[record["JobID"]] = record
    return jobs


def test_the_patch_workflow_on_slurm_equals_a_local_run(tmp_path):
    local, cluster = tmp_path / "local", tmp_path / "cluster"
    overlay = tmp_path / "ranks.yaml"
    overlay.write_text(yaml.safe_dump({"profiles": {"cpu": {"scenes": {"patch": {"training": {"ranks": 2}}}}}}))
    config = ["--configfile", str(REPO / "workflow_config.yaml"), str(overlay), "--"]
    run = snakemake(local, *config, "results/patch/")
    assert run.returncode == 0, tail(run)
    # The profile as a user runs it; --cores 2 only so that each job's threads (`workflow.cores`) are the local
    # run's: torch's sums, hence the bits, depend on the thread count.
    submitted = snakemake(cluster, "--profile", str(PROFILE), "--slurm-init-seconds-before-status-checks", "1",
                          *config, "results/patch/")
    assert submitted.returncode == 0, tail(submitted)
    log = submitted.stdout + submitted.stderr
    job_ids = re.findall(r"submitted with SLURM jobid (\d+)", log)
    assert len(job_ids) == len(CLUSTER_JOBS), log[-3000:]
    jobs = accounted_jobs(job_ids)
    assert set(jobs) == set(job_ids), "every submitted job is in the accounting"
    rules = {record["Comment"].removeprefix("rule_").split("_wildcards_")[0]: record for record in jobs.values()}
    assert set(rules) == CLUSTER_JOBS and not LOCAL_RULES & set(rules)
    assert {record["State"] for record in rules.values()} == {"COMPLETED"}

    # Each job asked for what its rule declares (threads, mem_mb) and the profile's runtime (minutes).
    profile = yaml.safe_load((PROFILE / "config.yaml").read_text())
    plan = subprocess.run([sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"), "--directory",
                           str(tmp_path / "plan"), "--cores", "2", "-n", "-F", *config, "results/patch/"],
                          capture_output=True, text=True)
    assert plan.returncode == 0, tail(plan)
    for rule, record in rules.items():
        declared = re.search(rf"rule {rule}:\n(?:    .*\n)*?    threads: (\d+)", plan.stdout)
        threads = int(declared[1]) if declared else 1
        mem = re.search(rf"rule {rule}:\n(?:    .*\n)*?    resources: .*\bmem_mb=(\d+)", plan.stdout)
        runtime = profile["set-resources"].get(rule, {}).get("runtime", profile["default-resources"]["runtime"])
        assert int(record["ReqCPUS"]) == threads, (rule, record)
        assert record["ReqMem"] == f"{mem[1]}M", (rule, record)
        hours, minutes = divmod(runtime, 60)
        assert record["Timelimit"] == f"{hours:02d}:{minutes:02d}:00", (rule, record)

    compare = subprocess.run([sys.executable, str(REPO / "tools" / "compare_results.py"),
                              str(local / "results" / "patch"), str(cluster / "results" / "patch")],
                             capture_output=True, text=True)
    assert compare.returncode == 0, compare.stdout[-3000:] + compare.stderr[-2000:]
    compared = int(re.search(r"(\d+) files compared, 0 differences", compare.stdout)[1])
    assert compared >= 12, compare.stdout        # settings ... eval.h5, report, renders, videos, export
    trained = torch.load(cluster / "results" / "patch" / "model.pt", weights_only=True)["training"]
    assert trained["ranks"] == 2
    assert "-m torch.distributed.run --standalone --nproc_per_node=2 -m pipeline.train" in log
