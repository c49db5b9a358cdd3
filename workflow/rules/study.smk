# The generalisation study (docs/performance.md): how the error on the held-out motion falls with the amount of
# training motion, per input variant. Its points (experiments.study.points, one folder each under
# `results/<scene>/study/`): `n<N>`, a dataset of the scene's first N training sequences (more made alike where N
# exceeds the scene's `sequences`: procedural motion, beside a motion library's) and every held-out one; `f<N>`,
# the scene's own dataset within N frames of whole training sequences; `oracle`, the scene's dataset with the
# held-out motion trained on too. Every network makes as many optimiser steps as `study.epochs` over the scene's
# sequences take (null: the scene's training.epochs), so that two points differ only in the motion they saw (at
# `study.width`, narrower than the scene's network where a grid of full-size trainings would not fit the device);
# each is evaluated; then one table and plot against the frames trained on. Target: `results/<scene>/study/`. The
# variant names (schema: letters, digits, _) and their inputs (schema: enums) are the only config values that
# reach a shell, quoted.

import experiments.study.points as study_points

STUDY = "results/{scene}/study"
STUDY_POINT = "results/{scene}/study/{point}"

wildcard_constraints:
    point="n[0-9]+|f[0-9]+|oracle",
    variant="[A-Za-z0-9_]+",


# Which sequences, flags and width each point has is experiments.study.points'; these feed it a scene's settings
# and sequences.
def study_sequence_files(name):
    return lambda w: [f"{folder}/{name}" for folder in study_sequence_folders(w)]


def study_sequence_folders(wildcards):
    return [f"results/{wildcards.scene}/sequences/{seq}"
            for seq in study_points.study_sequences(SEQUENCES[wildcards.scene], int(wildcards.point[1:]))]


def study_variant(wildcards):
    return SETTINGS[wildcards.scene]["study"]["variants"][wildcards.variant]


def study_point_dataset(wildcards):
    """A count point's own dataset, or the scene's."""
    if study_points.own_dataset(wildcards.point):
        return f"results/{wildcards.scene}/study/{wildcards.point}/dataset.h5"
    return f"results/{wildcards.scene}/dataset.h5"


rule study_dataset:
    wildcard_constraints: point="n[0-9]+"
    input:
        settings=f"{OUT}/simulation.json", subdiv=f"{OUT}/subdiv.h5", scenes=study_sequence_files("scene.h5"),
        sim_low=study_sequence_files("sim_low.h5"), sim_high=study_sequence_files("sim_high.h5"),
    output: f"{STUDY_POINT}/dataset.h5"
    params: sequences=study_sequence_folders
    log: f"{STUDY_POINT}/logs/dataset.log"
    benchmark: f"{STUDY_POINT}/benchmarks/dataset.tsv"
    threads: workflow.cores
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule study_train:
    input:
        settings=f"{OUT}/settings.json", dataset=study_point_dataset, operators=f"{OUT}/operators.h5"
    output: model=f"{STUDY_POINT}/{{variant}}/model.pt", history=f"{STUDY_POINT}/{{variant}}/train.h5"
    params:
        inputs=lambda w: ",".join(study_variant(w)["inputs"]),
        input_frame=lambda w: study_variant(w)["input_frame"],
        output_frame=lambda w: study_variant(w)["output_frame"],
        frame_tangent=lambda w: study_variant(w)["frame_tangent"],
        flags=lambda w: study_points.training_flags(SETTINGS[w.scene], w.point),
        width=lambda w: study_points.network_width(SETTINGS[w.scene]),
    log: f"{STUDY_POINT}/{{variant}}/logs/train.log"
    benchmark: f"{STUDY_POINT}/{{variant}}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --inputs {params.inputs:q} --input-frame {params.input_frame:q} "
        "--output-frame {params.output_frame:q} --frame-tangent {params.frame_tangent:q} "
        "{params.flags:q} --width {params.width:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# Errors only: no renders, one exported frame, no predicted positions in eval.h5.
rule study_evaluate:
    input:
        settings=f"{OUT}/settings.json", dataset=study_point_dataset, operators=f"{OUT}/operators.h5",
        model=f"{STUDY_POINT}/{{variant}}/model.pt",
    output:
        eval=f"{STUDY_POINT}/{{variant}}/eval.h5", report=f"{STUDY_POINT}/{{variant}}/report.md",
        export=directory(f"{STUDY_POINT}/{{variant}}/export"),
    log: f"{STUDY_POINT}/{{variant}}/logs/evaluate.log"
    benchmark: f"{STUDY_POINT}/{{variant}}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell: ERRORS_ONLY_EVALUATE


rule study:
    input: lambda w: [path for _, _, path in study_points.points(w.scene, SETTINGS[w.scene])]
    output: table=f"{STUDY}/study.h5", plot=f"{STUDY}/study.png", report=f"{STUDY}/report.md"
    params: points=lambda w: study_points.stage_arguments(w.scene, SETTINGS[w.scene])
    log: f"{STUDY}/logs/study.log"
    benchmark: f"{STUDY}/benchmarks/study.tsv"
    threads: 1
    resources: mem_mb=1000
    shell:
        "{PY:q} -m experiments.study {output.table:q} {output.plot:q} {output.report:q} {params.points:q} "
        "2>&1 | tee {log:q}"
