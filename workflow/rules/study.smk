# The generalisation study (docs/performance.md): how the error on the held-out motion falls with the amount of
# training motion, per input variant. For each n of study.sequence_counts a dataset of the scene's first n
# training sequences and every held-out one; for each variant a network trained on it for as many optimiser steps
# as `study.epochs` over the scene's sequences take (null: the scene's training.epochs; epochs times S / n, S = the
# scene's training sequences), so that two
# points differ only in the motion they saw (at `study.width`, narrower than the scene's network where a grid of
# full-size trainings would not fit the device); each evaluated; then one table and plot. A count above the scene's
# `sequences` makes the extra training sequences (seeded by their names, like the others). Target:
# `results/<scene>/study/`. The variant names (schema: letters, digits, _) and their inputs (schema: enums) are the
# only config values that reach a shell, quoted.

from scenes.sequences import HELD_OUT, TRAIN, parse_sequence_name, sequence_name

STUDY = "results/{scene}/study"
STUDY_POINT = "results/{scene}/study/n{n}"

wildcard_constraints:
    n="[0-9]+",
    variant="[A-Za-z0-9_]+",


def _study_sequences(wildcards):
    """The first `n` training sequences (the scene's, and more made the same way where `n` exceeds its
    `sequences`) and every held-out one."""
    held_out = [name for name in SEQUENCES[wildcards.scene] if parse_sequence_name(name)[0] == HELD_OUT]
    return [sequence_name(TRAIN, i) for i in range(int(wildcards.n))] + held_out


def study_sequence_files(name):
    return lambda w: [f"results/{w.scene}/sequences/{seq}/{name}" for seq in _study_sequences(w)]


def study_sequence_folders(wildcards):
    return [f"results/{wildcards.scene}/sequences/{seq}" for seq in _study_sequences(wildcards)]


def study_variant(wildcards):
    return SETTINGS[wildcards.scene]["study"]["variants"][wildcards.variant]


def study_epochs(wildcards):
    """Epochs over n sequences that make as many optimiser steps as `study.epochs` (null: the scene's own
    training.epochs) over the scene's sequences."""
    settings = SETTINGS[wildcards.scene]
    epochs = settings["study"]["epochs"] or settings["training"]["epochs"]
    return max(1, round(epochs * settings["sequences"] / int(wildcards.n)))


def study_points(scene):
    """(n, variant, eval.h5) of every point of a scene's study."""
    study = SETTINGS[scene]["study"]
    return [(n, variant, f"results/{scene}/study/n{n}/{variant}/eval.h5")
            for n in study["sequence_counts"] for variant in study["variants"]]


rule study_dataset:
    input:
        settings=f"{OUT}/simulation.json", subdiv=f"{OUT}/subdiv.h5", scenes=study_sequence_files("scene.h5"),
        sim_low=study_sequence_files("sim_low.h5"), sim_high=study_sequence_files("sim_high.h5"),
    output: f"{STUDY_POINT}/dataset.h5"
    params: sequences=study_sequence_folders
    log: f"{STUDY_POINT}/logs/dataset.log"
    benchmark: f"{STUDY_POINT}/benchmarks/dataset.tsv"
    threads: 1
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --quiet 2>&1 | tee {log:q}"


rule study_train:
    input:
        settings=f"{OUT}/settings.json", dataset=f"{STUDY_POINT}/dataset.h5", operators=f"{OUT}/operators.h5"
    output: model=f"{STUDY_POINT}/{{variant}}/model.pt", history=f"{STUDY_POINT}/{{variant}}/train.h5"
    params:
        inputs=lambda w: ",".join(study_variant(w)["inputs"]),
        input_frame=lambda w: study_variant(w)["input_frame"],
        output_frame=lambda w: study_variant(w)["output_frame"],
        frame_tangent=lambda w: study_variant(w)["frame_tangent"],
        epochs=study_epochs,
        width=lambda w: SETTINGS[w.scene]["study"]["width"] or SETTINGS[w.scene]["network"]["width"],
    log: f"{STUDY_POINT}/{{variant}}/logs/train.log"
    benchmark: f"{STUDY_POINT}/{{variant}}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --inputs {params.inputs:q} --input-frame {params.input_frame:q} "
        "--output-frame {params.output_frame:q} --frame-tangent {params.frame_tangent:q} "
        "--epochs {params.epochs:q} --width {params.width:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# Errors only: no renders, one exported frame, no predicted positions in eval.h5.
rule study_evaluate:
    input:
        settings=f"{OUT}/settings.json", dataset=f"{STUDY_POINT}/dataset.h5", operators=f"{OUT}/operators.h5",
        model=f"{STUDY_POINT}/{{variant}}/model.pt",
    output:
        eval=f"{STUDY_POINT}/{{variant}}/eval.h5", report=f"{STUDY_POINT}/{{variant}}/report.md",
        export=directory(f"{STUDY_POINT}/{{variant}}/export"),
    log: f"{STUDY_POINT}/{{variant}}/logs/evaluate.log"
    benchmark: f"{STUDY_POINT}/{{variant}}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
        "{output.report:q} --export {output.export:q} --render-frames 0 --video-frames 0 "
        "--export-frames 1 --no-predictions --settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule study:
    input: lambda w: [path for _, _, path in study_points(w.scene)]
    output: table=f"{STUDY}/study.h5", plot=f"{STUDY}/study.png", report=f"{STUDY}/report.md"
    params: points=lambda w: [str(x) for point in study_points(w.scene) for x in ("--point", *point)]
    log: f"{STUDY}/logs/study.log"
    benchmark: f"{STUDY}/benchmarks/study.tsv"
    threads: 1
    resources: mem_mb=1000
    shell:
        "{PY:q} -m experiments.study {output.table:q} {output.plot:q} {output.report:q} {params.points:q} "
        "2>&1 | tee {log:q}"
