"""The paths and names the workflow gives a scene's stage chain and its applications (the Snakefile,
workflow/rules/common.smk, simulate.smk, applications.smk): from a scene's name, its resolved settings and its
sequence names, what `results/<scene>/`, `results/<scene>/pose/` and `results/<scene>/pca/` stand for, each
sequence's files, the settle run a motion library's windows start from, the motion-capture files a scene needs, which operators.h5 an application reads and the names of
sharded scenes' batch rules. The experiment families lay out theirs beside their code (experiments.tradeoff.grid,
experiments.study.points, experiments.multi.garments). The Snakefile imports this at every start: it reads
settings only and imports nothing heavy.
"""
from __future__ import annotations

import os
import re
from typing import Any, Callable, Iterable

from pipeline.core.config import application_settings
from pipeline.core.errors import PipelineError
from scenes.sequences import is_hand, is_window_name, sequence_bvh_files, wears_garment

Settings = dict[str, Any]

# What `results/<scene>/` stands for: every final product of a scene (the rest are their inputs).
SCENE_PRODUCTS = ("operators.h5", "dataset.h5", "model.pt", "train.h5", "eval.h5", "report.md", "report.html",
                  "renders", "videos", "export")
SEQUENCE_PRODUCTS = ("sim_low.h5", "sim_high.h5")
# The hand scene's (mesh.generator hand, workflow/rules/hand.smk): its skin and tet volume, a FEM run a sequence.
HAND_MESH, HAND_RUN = "hand.h5", "fem.h5"
# What each model folder of an application (pose, pca/k<K>) holds.
APPLICATION_PRODUCTS = ("dataset.h5", "model.pt", "train.h5", "eval.h5", "report.md", "report.html", "renders",
                        "videos", "export")


def one_of(names: Iterable[str]) -> str:
    """A wildcard constraint that matches exactly one of `names`; with none, one that matches nothing."""
    return "|".join(map(re.escape, names)) or "(?!)"


def train_launcher(settings: Settings) -> list[str]:
    """What comes between the interpreter and `-m pipeline.train` in the train job: nothing for one process;
    torchrun (`python -m torch.distributed.run`, on this machine, a free port of its own) for `training.ranks`
    processes."""
    ranks = settings["training"]["ranks"]
    return [] if ranks == 1 else ["-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}"]


def train_gpus(settings: Settings, jobs_per_gpu: int = 1) -> int:
    """GPU slots the train job asks for (`--resources gpu`): none on the CPU; on a CUDA device one for a single
    process, and for several ranks every slot of a GPU a rank (each takes its GPU whole: pipeline.train)."""
    if not settings["device"].startswith("cuda"):
        return 0
    ranks = settings["training"]["ranks"]
    return ranks * jobs_per_gpu if ranks > 1 else 1


def rank_threads(settings: Settings, threads: int) -> int:
    """CPU threads of each of the train job's ranks: the job's threads shared out, at least one each."""
    return max(1, threads // settings["training"]["ranks"])


def batch_rule_name(stage: str, scene: str, shard: int) -> str:
    """The name of the rule that runs `stage` on shard `shard` of a sharded scene: a Python identifier (the
    scene's other characters become _), one per scene and shard."""
    return f"{stage}_batch_{re.sub(r'[^A-Za-z0-9_]', '_', scene)}_{shard:03d}"


def sequence_folders(scene: str, sequences: list[str]) -> list[str]:
    """Every sequence folder of the scene, in order: the dataset's arguments."""
    return [f"results/{scene}/sequences/{seq}" for seq in sequences]


def sequence_files(scene: str, sequences: list[str], name: str) -> list[str]:
    """Artifact `name` of every sequence of the scene, in order."""
    return [f"{folder}/{name}" for folder in sequence_folders(scene, sequences)]


def sequence_products(settings: Settings) -> tuple[str, ...]:
    """What each sequence of the scene is simulated into: the cloth's two runs, or the hand's FEM run."""
    return (HAND_RUN,) if is_hand(settings) else SEQUENCE_PRODUCTS


def operators_mesh(scene: str, settings: Settings) -> str:
    """The mesh a scene's operators are built on: the subdivided cloth (subdiv.h5) or the hand's skin (hand.h5)."""
    return f"results/{scene}/{HAND_MESH if is_hand(settings) else 'subdiv.h5'}"


def scene_products(scene: str, sequences: list[str], per_sequence: tuple[str, ...] = SEQUENCE_PRODUCTS) -> list[str]:
    """What `results/<scene>/` stands for: each sequence's runs (`per_sequence`: sequence_products), then the
    scene's products."""
    return ([f"results/{scene}/sequences/{seq}/{name}" for seq in sequences for name in per_sequence]
            + [f"results/{scene}/{name}" for name in SCENE_PRODUCTS])


def subdiv_file(scene: str) -> str:
    """The scene's subdiv.h5: its low- and high-res vertex counts say what a frame weighs on disk."""
    return f"results/{scene}/subdiv.h5"


def settle_folder(scene: str) -> str:
    """Where a scene with a motion library keeps its settle sequence (scenes.sequences.SETTLE): scene.h5 and its
    runs, apart from the sequences the dataset gathers."""
    return f"results/{scene}/settle"


def garment_files(settings: Settings) -> list[str]:
    """The user's garment file a garment_file scene is dressed from: editing it dresses the garment again."""
    return [settings["mesh"]["file"]] if settings["mesh"]["generator"] == "garment_file" else []


def hand_files(settings: Settings) -> list[str]:
    """The user's skin and bone files a hand_file scene's hand.h5 is made from: editing either makes it again."""
    mesh = settings["mesh"]
    return [mesh["file"], mesh["bones"]] if mesh["generator"] == "hand_file" else []


def settled_runs(scene: str, sequences: Iterable[str], level: str) -> list[str]:
    """The settle run that a simulate job of these sequences starts from at `level` (low, high): the scene's when
    one of them is a motion library's window, none otherwise."""
    return [f"{settle_folder(scene)}/sim_{level}.h5"] if any(map(is_window_name, sequences)) else []


def settled_flag(scene: str, sequences: Iterable[str], level: str) -> list[str]:
    """The simulate stage's `--settled RUN` for settled_runs, or nothing."""
    return [flag for run in settled_runs(scene, sequences, level) for flag in ("--settled", run)]


def sequences_or_error(scene: str, names: Callable[[], list[str]]) -> list[str]:
    """A scene's sequence names; a motion library that cannot be listed (its folder or manifest missing or
    unreadable: scenes.library raises ValueError naming the path) becomes one error naming the scene."""
    try:
        return names()
    except ValueError as err:
        raise PipelineError(f"scene '{scene}': {err}") from None


def check_bvh_files(scene: str, settings: Settings, sequences: list[str]) -> None:
    """Every motion-capture file the scene's sequences play exists (relative paths start in the working
    directory): found missing before any job starts, it is one error naming the file instead of a missing input
    of some job."""
    for path in sorted({p for name in sequences for p in sequence_bvh_files(settings, name)}):
        if not os.path.isfile(path):
            raise PipelineError(f"{path}: BVH file of scene '{scene}' does not exist (working directory "
                                f"{os.getcwd()})")


def check_user_files(scene: str, settings: Settings) -> None:
    """A garment_file scene's garment file, a hand_file scene's skin and bone files exist (as check_bvh_files for
    motion files)."""
    keys = dict(zip(hand_files(settings), ("mesh.file", "mesh.bones")))
    for path in garment_files(settings) + hand_files(settings):
        if not os.path.isfile(path):
            kind, key = ("hand file", keys[path]) if path in keys else ("garment file", "mesh.file")
            raise PipelineError(f"{path}: {kind} of scene '{scene}' ({key}) does not exist (working directory "
                                f"{os.getcwd()})")


# The folders of results/<scene>/ built on a cloth scene's low- and high-res runs: the study, the trade-off, the
# operator comparison (upsampling networks) and the pose and PCA applications. A hand scene has none of them.
CLOTH_EXPERIMENTS = ("study", "tradeoff", "convs", "pose", "pca")


def check_targets(targets: Iterable[str], settings: dict[str, Settings]) -> None:
    """A target inside results/<hand scene>/ that only a cloth scene has is one error naming the hand's own target
    (without the check Snakemake would look for cloth runs the hand never makes and fail far from the cause)."""
    for target in targets:
        parts = os.path.normpath(target).split(os.sep)
        if (len(parts) > 2 and parts[0] == "results" and parts[1] in settings and is_hand(settings[parts[1]])
                and parts[2] in CLOTH_EXPERIMENTS):
            raise PipelineError(f"{target}: '{parts[2]}' is made from a cloth scene's runs, and '{parts[1]}' is a "
                                f"hand scene (its network a decoder of the joint angles, its data FEM runs): its "
                                f"target is results/{parts[1]}/")


def application_of(model_dir: str) -> str:
    """The application (pose, pca) of a model folder (pose, pca/k<K>)."""
    return model_dir.split("/")[0]


def application_operators(scene: str, settings: Settings, application: str) -> str:
    """The scene's operators.h5 where the application's operators settings are the scene's, its own otherwise."""
    if application_settings(settings, application)["operators"] == settings["operators"]:
        return f"results/{scene}/operators.h5"
    return f"results/{scene}/{application}/operators.h5"


def pca_model_dirs(settings: Settings) -> list[str]:
    """A model folder per PCA component count, in config order."""
    return [f"pca/k{k}" for k in settings["applications"]["pca"]["components"]]


def pca_summary_arguments(scene: str, settings: Settings) -> list[str]:
    """`--model K EVAL.h5` for each component count."""
    return [str(x) for k in settings["applications"]["pca"]["components"]
            for x in ("--model", k, f"results/{scene}/pca/k{k}/eval.h5")]


def application_products(scene: str, settings: Settings, application: str) -> list[str]:
    """What `results/<scene>/<application>/` stands for; a scene without a mannequin has no pose input, said in
    one line before any job runs."""
    if application == "pose" and not wears_garment(settings):
        raise PipelineError(f"results/{scene}/pose/: scene '{scene}' has no mannequin, so no pose input (pose to "
                            f"cloth needs a garment scene, mesh.generator 'garment' or 'garment_file')")
    folders = ["pose"] if application == "pose" else pca_model_dirs(settings)
    summary = [f"results/{scene}/pca/report.md"] if application == "pca" else []
    return [f"results/{scene}/{folder}/{name}" for folder in folders for name in APPLICATION_PRODUCTS] + summary
