# Shared by the rule files: every scene's resolved settings, the wildcard constraint, the per-scene paths and the
# functions the rules read (resources from a scene's settings, what `results/<scene>/` stands for).
import re
import sys

from pipeline.config import resolve_scene

# Resolving every scene now turns a bad or missing key into one error before any job starts.
SETTINGS = {scene: resolve_scene(config, scene) for scene in config["scenes"]}
# The interpreter running Snakemake (the project's venv): jobs run the stages as `{PY} -m pipeline.<stage>`,
# which works from any working directory once the project is installed (`pip install -e .`).
PY = sys.executable
OUT = "results/{scene}"

wildcard_constraints:
    scene="|".join(map(re.escape, SETTINGS)),


def log_of(rule_name):
    """Where a job's stderr (and stdout) is kept, next to the artifacts it explains."""
    return f"{OUT}/logs/{rule_name}.log"


def benchmark_of(rule_name):
    """Snakemake's wall time, CPU time and peak memory of a job (the numbers behind `mem_mb`)."""
    return f"{OUT}/benchmarks/{rule_name}.tsv"


def gpus_on_device(wildcards):
    """One GPU for a job that runs on the scene's device when that device is CUDA, none otherwise."""
    return int(SETTINGS[wildcards.scene]["device"].startswith("cuda"))


# What `results/<scene>/` stands for: every final product of a scene (the rest are their inputs).
PRODUCTS = ("sim_low.h5", "sim_high.h5", "operators.h5", "dataset.h5", "model.pt", "train.h5", "eval.h5",
            "report.md", "renders", "export")


def scene_products(scene):
    return [f"results/{scene}/{name}" for name in PRODUCTS]
