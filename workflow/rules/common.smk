# Shared by the rule files: every scene's resolved settings and sequences, the wildcard constraints, the paths
# and the functions the rules read (resources from a scene's settings, what `results/<scene>/` stands for). The
# paths' logic is pipeline.workflow_paths'; the functions here feed it a scene's settings and sequences.
import os
import sys

from pipeline import workflow_paths, workflow_plan
from pipeline.core import gpu_slots
from pipeline.core.cli import exit_on_error
from pipeline.core.config import shared_settings, simulation_settings
from scenes.sequences import NAME_PATTERN, library_of, sequence_bvh_files, sequence_shards

# Every scene resolved, its sequences listed (the count is in SETTINGS, not in settings.json, so raising it adds
# sequences without touching an input of those already made), its motion-capture files found and its cost
# stated (and the disk of the scenes the targets name), before any job exists: a problem is one error line
# (pipeline.workflow_plan).
SETTINGS, SEQUENCES = exit_on_error(workflow_plan.plan, config, workflow.is_main_process,
                                    workflow.dag_settings.targets if workflow.dag_settings else ())
# The interpreter running Snakemake (the project's venv): jobs run the stages as `{PY} -m pipeline.<stage>`,
# which works from any working directory once the project is installed (`pip install -e .`).
PY = sys.executable
OUT = "results/{scene}"
# The evaluate stage's errors and timing only (no renders, one exported frame, no predicted positions in eval.h5,
# the fp32 deployment path timed but not the fused bf16 network, which no grid's table reads: the trade-off times
# its networks itself): the shell of the grids' evaluations (study, trade-off, operator comparison), whose rules
# name their inputs dataset, operators, model, settings and their outputs eval, report, export.
ERRORS_ONLY_EVALUATE = (
    "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
    "{output.report:q} --export {output.export:q} --render-frames 0 --video-frames 0 --export-frames 1 "
    "--no-predictions --no-fused-timing --settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}")
SEQ = "results/{scene}/sequences/{seq}"    # one sequence's scene.h5, sim_low.h5, sim_high.h5
# The scenes with a motion library, whose windows start from their settle sequence's runs (results/<scene>/settle/)
LIBRARY_SCENES = workflow_paths.one_of(s for s, settings in SETTINGS.items() if library_of(settings) is not None)
# The scenes of a garment from a file, dressed on the mannequin first (results/<scene>/dressed.h5).
FILE_SCENES = workflow_paths.one_of(s for s, settings in SETTINGS.items() if workflow_paths.garment_files(settings))

# Several GPUs: each CUDA job takes a free one (pipeline.core.gpu_slots), told how many through its environment.
os.environ[gpu_slots.GPUS_VARIABLE] = str(config.get("gpus", 1))
JOBS_PER_GPU = config.get("jobs_per_gpu", 1)
os.environ[gpu_slots.JOBS_PER_GPU_VARIABLE] = str(JOBS_PER_GPU)

wildcard_constraints:
    scene=workflow_paths.one_of(SETTINGS),
    seq=NAME_PATTERN,

def log_of(rule_name, per_sequence=False):
    """Where a job's stderr (and stdout) is kept, next to the artifacts it explains."""
    return f"{OUT}/logs/{{seq}}/{rule_name}.log" if per_sequence else f"{OUT}/logs/{rule_name}.log"


def benchmark_of(rule_name, per_sequence=False):
    """Snakemake's wall time, CPU time and peak memory of a job (the numbers behind `mem_mb`)."""
    return f"{OUT}/benchmarks/{{seq}}/{rule_name}.tsv" if per_sequence else f"{OUT}/benchmarks/{rule_name}.tsv"


def device_gpus(scene):
    """One GPU for a job that runs on the scene's device when that device is CUDA, none otherwise."""
    return int(SETTINGS[scene]["device"].startswith("cuda"))


def gpus_on_device(wildcards):
    return device_gpus(wildcards.scene)


def whole_gpus_on_device(wildcards):
    """A job that takes its GPU whole (pipeline.core.gpu_slots, `whole`) asks for all of its slots."""
    return device_gpus(wildcards.scene) * JOBS_PER_GPU


# The trainings of the scene's own recipe (its network, and the trade-off's matched networks: that recipe on the
# inputs a cheaper low-res run gives) run its `training.ranks` processes under torchrun, a GPU each, so that a
# matched network is trained as the network it is compared with. The grids' trainings of their own step budgets
# (study, trade-off widths, operator comparison, applications) run one process each, many at a time.
def recipe_train_launcher(wildcards):
    return workflow_paths.train_launcher(SETTINGS[wildcards.scene])


def recipe_train_gpus(wildcards):
    return workflow_paths.train_gpus(SETTINGS[wildcards.scene], JOBS_PER_GPU)


def recipe_train_threads(wildcards, threads):
    return workflow_paths.rank_threads(SETTINGS[wildcards.scene], threads)


def high_batch_threads(scene, sequences):
    """Threads of a high-res batch job: on a GPU one a sequence, up to 8, for the per-sequence work outside the
    solver (harmonic targets, residual: most of a 64-sequence job's time besides stepping); a CPU batch steps on
    one thread for hours, so it holds one core."""
    return min(sequences, 8) if device_gpus(scene) else 1


def bvh_files(wildcards):
    """The motion-capture files a sequence reads: editing one remakes the sequences that play it."""
    return sequence_bvh_files(SETTINGS[wildcards.scene], wildcards.seq)


def sequence_files(name):
    """An input function: artifact `name` of every sequence of the scene."""
    return lambda w: workflow_paths.sequence_files(w.scene, SEQUENCES[w.scene], name)


def sequence_folders(wildcards):
    return workflow_paths.sequence_folders(wildcards.scene, SEQUENCES[wildcards.scene])


def scene_products(scene):
    """What `results/<scene>/` stands for."""
    return workflow_paths.scene_products(scene, SEQUENCES[scene], workflow_paths.sequence_products(SETTINGS[scene]))


def operators_mesh(wildcards):
    """The mesh the scene's operators are built on (the subdivided cloth, or the hand's skin)."""
    return workflow_paths.operators_mesh(wildcards.scene, SETTINGS[wildcards.scene])


def settled_runs(level, sequences=lambda w: [w.seq]):
    """An input function: the settle run a simulate job of `sequences(wildcards)` (default: the job's sequence)
    starts from at `level`, if one of them is a library's window."""
    return lambda w: workflow_paths.settled_runs(w.scene, sequences(w), level)


def settled_flag(level, sequences=lambda w: [w.seq]):
    """A params function: the simulate stage's `--settled RUN` for settled_runs, or nothing."""
    return lambda w: workflow_paths.settled_flag(w.scene, sequences(w), level)
