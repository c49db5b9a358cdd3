# The paper's decoder applications beside the upsampling (paper Table 2 rows 2-3, Table 4; docs/architecture.md,
# "Applications"): `results/<scene>/pose/` (pose to cloth: the mannequin's pose -> cloth over linear blend
# skinning) and `results/<scene>/pca/` (PCA details recovery: one model per component count in pca/k<K>/, and a
# table over them). Each runs the same dataset, train and evaluate stages as the upsampling, with `--task`, on the
# scene's sequences; its stages read results/<scene>/<application>/settings.json, the scene's settings with
# `applications.<application>` merged over them. An application whose operators settings differ from the scene's
# (more levels for the decoder's unpoolings) gets its own operators.h5. None of this is part of `results/<scene>/`:
# `make run` does not grow. The only values that reach a shell besides paths are the literal task names and the
# component count (a folder name, digits).
from pipeline.core.config import application_settings

APPLICATION = "results/{scene}/{application}"     # pose or pca: settings.json, operators.h5
MODEL_DIR = "results/{scene}/{model_dir}"          # pose, or pca/k<K>: dataset.h5, model.pt, ... report.md

wildcard_constraints:
    application="pose|pca",
    model_dir="pose|pca/k[0-9]+",
    components="[0-9]+",


# Which operators.h5 a model folder reads and what each target stands for are pipeline.workflow_paths'; these feed
# it a scene's settings.
def application_settings_file(wildcards):
    return f"results/{wildcards.scene}/{workflow_paths.application_of(wildcards.model_dir)}/settings.json"


def application_operators(wildcards):
    return workflow_paths.application_operators(wildcards.scene, SETTINGS[wildcards.scene],
                                                workflow_paths.application_of(wildcards.model_dir))


def application_products(scene, application):
    """An input function: what `results/<scene>/<application>/` stands for, resolved only when asked for."""
    return lambda wildcards: workflow_paths.application_products(scene, SETTINGS[scene], application)


rule application_settings:
    output: f"{APPLICATION}/settings.json"
    params: settings=lambda w: application_settings(SETTINGS[w.scene], w.application)
    log: f"{APPLICATION}/logs/settings.log"
    benchmark: f"{APPLICATION}/benchmarks/settings.tsv"
    localrule: True     # a JSON file: in Snakemake's own process, never a cluster job
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with applications.{wildcards.application}", file=f)


rule application_operators:
    input: settings=f"{APPLICATION}/settings.json", subdiv=f"{OUT}/subdiv.h5"
    output: f"{APPLICATION}/operators.h5"
    log: f"{APPLICATION}/logs/operators.log"
    benchmark: f"{APPLICATION}/benchmarks/operators.tsv"
    threads: 1
    resources: mem_mb=4000
    shell:
        "{PY:q} -m pipeline.operators {input.subdiv:q} {output:q} --settings {input.settings:q} --quiet "
        "2>&1 | tee {log:q}"


rule pose_dataset:
    input:
        settings="results/{scene}/pose/settings.json", subdiv=f"{OUT}/subdiv.h5", scenes=sequence_files("scene.h5"),
        sim_low=sequence_files("sim_low.h5"), sim_high=sequence_files("sim_high.h5"),
    output: "results/{scene}/pose/dataset.h5"
    params: sequences=sequence_folders
    log: "results/{scene}/pose/logs/dataset.log"
    benchmark: "results/{scene}/pose/benchmarks/dataset.tsv"
    threads: workflow.cores
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} --task pose "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule pca_dataset:
    input:
        settings="results/{scene}/pca/settings.json", subdiv=f"{OUT}/subdiv.h5", scenes=sequence_files("scene.h5"),
        sim_low=sequence_files("sim_low.h5"), sim_high=sequence_files("sim_high.h5"),
    output: "results/{scene}/pca/k{components}/dataset.h5"
    params: sequences=sequence_folders
    log: "results/{scene}/pca/k{components}/logs/dataset.log"
    benchmark: "results/{scene}/pca/k{components}/benchmarks/dataset.tsv"
    threads: workflow.cores
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} --task pca "
        "--components {wildcards.components:q} --settings {input.settings:q} --threads {threads} --quiet "
        "2>&1 | tee {log:q}"


rule application_train:
    input: settings=application_settings_file, dataset=f"{MODEL_DIR}/dataset.h5", operators=application_operators
    output: model=f"{MODEL_DIR}/model.pt", history=f"{MODEL_DIR}/train.h5"
    log: f"{MODEL_DIR}/logs/train.log"
    benchmark: f"{MODEL_DIR}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule application_evaluate:
    input:
        settings=application_settings_file, dataset=f"{MODEL_DIR}/dataset.h5", operators=application_operators,
        model=f"{MODEL_DIR}/model.pt", train_log=f"{MODEL_DIR}/train.h5",
    output:
        eval=f"{MODEL_DIR}/eval.h5", report=f"{MODEL_DIR}/report.md", html=f"{MODEL_DIR}/report.html",
        renders=directory(f"{MODEL_DIR}/renders"), videos=directory(f"{MODEL_DIR}/videos"),
        export=directory(f"{MODEL_DIR}/export"),
    log: f"{MODEL_DIR}/logs/evaluate.log"
    benchmark: f"{MODEL_DIR}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
        "{output.report:q} --html {output.html:q} --train-log {input.train_log:q} --scene {input.dataset:q} "
        "--renders {output.renders:q} --videos {output.videos:q} --export {output.export:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# The PCA models side by side: how much of the truncation error each recovers.
rule pca_summary:
    input:
        lambda w: [f"results/{w.scene}/{folder}/eval.h5" for folder in workflow_paths.pca_model_dirs(SETTINGS[w.scene])]
    output: "results/{scene}/pca/report.md"
    params: models=lambda w: workflow_paths.pca_summary_arguments(w.scene, SETTINGS[w.scene])
    log: "results/{scene}/pca/logs/summary.log"
    benchmark: "results/{scene}/pca/benchmarks/summary.tsv"
    threads: 1
    resources: mem_mb=1000
    shell: "{PY:q} -m experiments.pca {output:q} {params.models:q} 2>&1 | tee {log:q}"


# `results/<scene>/pose/` and `results/<scene>/pca/` as targets (see the Snakefile's `results/<scene>/`), with and
# without the trailing slash; what they stand for is resolved only when asked for.
for _scene in SETTINGS:
    for _application in ("pose", "pca"):
        for _target in (f"results/{_scene}/{_application}/", f"results/{_scene}/{_application}"):
            rule:
                name: _target
                input: application_products(_scene, _application)
