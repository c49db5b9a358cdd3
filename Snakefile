# Wiring only: every stage is a `python -m pipeline.<stage>` CLI that reads and writes HDF5 artifacts under
# results/{scene}/, a sequence's under results/{scene}/sequences/{seq}/. A bare `snakemake --cores 2` builds the
# config's `default_scene`; `results/<scene>/` builds everything a scene has; any artifact path is a target too
# (e.g. results/patch/sequences/train_000/sim_high.h5), and `--forcerun <rule>` reruns one stage. The rules live
# in workflow/rules/: common.smk (settings and sequences per scene, paths, input functions), scene.smk,
# simulate.smk, learning.smk, study.smk (`results/<scene>/study/`: error against the amount of training motion),
# applications.smk (`results/<scene>/pose/`, `pca/`), tradeoff.smk (`results/<scene>/tradeoff/`: speed against
# accuracy), multi.smk (`results/multi/`: one network for several garments), convs.smk (`results/<scene>/convs/`: the
# operators RC, EC, SP and SPD side by side), hand.smk (the FEM hand's mesh, runs and dataset: joint angles -> skin).
import os

from snakemake.utils import min_version, validate

from pipeline.core.cli import exit_on_error
from pipeline.core.config import validate_config

min_version("9.0")

# Beside this file, so that `-s path/to/Snakefile` and `--directory elsewhere` find it; `--configfile` and
# `--config` merge over it.
configfile: os.path.join(workflow.basedir, "workflow_config.yaml")

# Our validator first: it names the offending key in one line (and stops, not followed by Snakemake's stack of
# Snakefile frames); Snakemake's then records the schema check.
exit_on_error(validate_config, config, "workflow config")
validate(config, "workflow/config.schema.yaml")

include: "workflow/rules/common.smk"
include: "workflow/rules/scene.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/learning.smk"
include: "workflow/rules/hand.smk"
include: "workflow/rules/study.smk"
include: "workflow/rules/applications.smk"
include: "workflow/rules/tradeoff.smk"
include: "workflow/rules/multi.smk"
include: "workflow/rules/convs.smk"

rule all:
    default_target: True
    input: scene_products(config["default_scene"])


# `results/<scene>/` as a target: a rule named after the folder (a directory output would clash with the
# artifacts inside it), with and without the trailing slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/", f"results/{_scene}"):
        rule:
            name: _target
            input: scene_products(_scene)
    for _target in (f"results/{_scene}/study/", f"results/{_scene}/study"):
        rule:
            name: _target
            input: [f"results/{_scene}/study/{name}" for name in ("study.h5", "study.png", "report.md")]
