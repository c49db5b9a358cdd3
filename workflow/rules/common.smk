# Shared by the rule files: every scene's resolved settings and sequences, the wildcard constraints, the paths
# and the functions the rules read (resources from a scene's settings, what `results/<scene>/` stands for).
import os
import re
import sys

from pipeline.core.config import resolve_scene, shared_settings, simulation_settings
from pipeline.core.errors import PipelineError
from scenes.sequences import NAME_PATTERN, sequence_bvh_files, sequence_names, sequence_shards

# Resolving every scene now turns a bad or missing key into one error before any job starts.
SETTINGS = {scene: resolve_scene(config, scene) for scene in config["scenes"]}
# Each scene's sequences (train_000, ..., held_out_000, ...): the count is in SETTINGS, not in settings.json, so
# raising it adds sequences without touching an input of those already made.
SEQUENCES = {scene: sequence_names(settings) for scene, settings in SETTINGS.items()}
# The interpreter running Snakemake (the project's venv): jobs run the stages as `{PY} -m pipeline.<stage>`,
# which works from any working directory once the project is installed (`pip install -e .`).
PY = sys.executable
OUT = "results/{scene}"
SEQ = "results/{scene}/sequences/{seq}"    # one sequence's scene.h5, sim_low.h5, sim_high.h5

wildcard_constraints:
    scene="|".join(map(re.escape, SETTINGS)),
    seq=NAME_PATTERN,

# A motion-capture file a scene names must exist (relative paths start in the working directory); found missing
# here, it is one error naming the file instead of a missing input of some job.
for _scene, _names in SEQUENCES.items():
    for _path in sorted({p for name in _names for p in sequence_bvh_files(SETTINGS[_scene], name)}):
        if not os.path.isfile(_path):
            raise PipelineError(f"{_path}: BVH file of scene '{_scene}' does not exist (working directory "
                                f"{os.getcwd()})")


def log_of(rule_name, per_sequence=False):
    """Where a job's stderr (and stdout) is kept, next to the artifacts it explains."""
    return f"{OUT}/logs/{{seq}}/{rule_name}.log" if per_sequence else f"{OUT}/logs/{rule_name}.log"


def benchmark_of(rule_name, per_sequence=False):
    """Snakemake's wall time, CPU time and peak memory of a job (the numbers behind `mem_mb`)."""
    return f"{OUT}/benchmarks/{{seq}}/{rule_name}.tsv" if per_sequence else f"{OUT}/benchmarks/{rule_name}.tsv"


def gpus_on_device(wildcards):
    """One GPU for a job that runs on the scene's device when that device is CUDA, none otherwise."""
    return int(SETTINGS[wildcards.scene]["device"].startswith("cuda"))


def batch_rule_name(stage, scene, shard):
    """The name of the rule that runs `stage` on shard `shard` of a sharded scene: a Python identifier (the
    scene's other characters become _), one per scene and shard."""
    return f"{stage}_batch_{re.sub(r'[^A-Za-z0-9_]', '_', scene)}_{shard:03d}"


def high_batch_threads(scene, sequences):
    """Threads of a high-res batch job: on a GPU one a sequence, up to 8, for the per-sequence work outside the
    solver (harmonic targets, residual: most of a 64-sequence job's time besides stepping); a CPU batch steps on
    one thread for hours, so it holds one core."""
    return min(sequences, 8) if SETTINGS[scene]["device"].startswith("cuda") else 1


def bvh_files(wildcards):
    """The motion-capture files a sequence reads: editing one remakes the sequences that play it."""
    return sequence_bvh_files(SETTINGS[wildcards.scene], wildcards.seq)


def sequence_files(name):
    """An input function: artifact `name` of every sequence of the scene."""
    return lambda wildcards: [f"results/{wildcards.scene}/sequences/{seq}/{name}"
                              for seq in SEQUENCES[wildcards.scene]]


def sequence_folders(wildcards):
    """Every sequence folder of the scene, in order: the dataset's arguments."""
    return [f"results/{wildcards.scene}/sequences/{seq}" for seq in SEQUENCES[wildcards.scene]]


# What `results/<scene>/` stands for: every final product of a scene (the rest are their inputs).
PRODUCTS = ("operators.h5", "dataset.h5", "model.pt", "train.h5", "eval.h5", "report.md", "report.html", "renders",
            "videos", "export")
SEQUENCE_PRODUCTS = ("sim_low.h5", "sim_high.h5")


def scene_products(scene):
    return ([f"results/{scene}/sequences/{seq}/{name}" for seq in SEQUENCES[scene] for name in SEQUENCE_PRODUCTS]
            + [f"results/{scene}/{name}" for name in PRODUCTS])
