# The paper's operator comparison (supplementary Tables 1, 2, 4; docs/performance.md): the scene's network trained
# with each operator of `convs.kinds` at each length of `convs.lengths`, for each architecture of `convs.archs` (the
# scene's, and templates in x sized to its parameter count) and each seed of `convs.seeds`, on the scene's dataset,
# with the scene's recipe (`convs.epochs` apart); the pose-to-cloth decoder likewise on the pose application's
# dataset where the scene has a mannequin (`convs.pose`). What is run is experiments.convs.grid's: one folder per run,
# results/<scene>/convs/<task>/a<k>/<conv>/s<seed>/, trained, evaluated (errors and timing only), then one table,
# chart and report. Every run reads one operators.h5 holding every operator of the grid. Target:
# `results/<scene>/convs/`. The architecture strings (schema: D tokens, x, digits, _) are the only config values
# that reach a shell, quoted.

import experiments.convs.grid as convs_grid

CONVS = "results/{scene}/convs"
CONVS_RUN = "results/{scene}/convs/{task}/{arch}/{conv}/s{seed}"

wildcard_constraints:
    task="upsampling|pose",
    arch="a[0-9]+",
    conv="(RC|EC|SP|SPD)[0-9]+",
    seed="[0-9]+",

# Every scene's architectures resolved before any job: a template that cannot be sized is one error line. A hand
# scene's own network is a decoder (its input is 18 angles, not a mesh): it has no upsampling to compare.
for _scene in (s for s in SETTINGS if not workflow_paths.is_hand(SETTINGS[s])):
    exit_on_error(convs_grid.check, SETTINGS[_scene])


rule convs_operators_settings:
    output: f"{CONVS}/settings.json"
    params: settings=lambda w: convs_grid.operators_settings(SETTINGS[w.scene])
    log: f"{CONVS}/logs/settings.log"
    benchmark: f"{CONVS}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with every operator of the grid", file=f)


rule convs_task_settings:
    output: f"{CONVS}/{{task}}/settings.json"
    params: settings=lambda w: convs_grid.task_settings(SETTINGS[w.scene], w.task)
    log: f"{CONVS}/logs/{{task}}_settings.log"
    benchmark: f"{CONVS}/benchmarks/{{task}}_settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the {wildcards.task} task's settings with the grid's operators and epochs", file=f)


rule convs_operators:
    input: settings=f"{CONVS}/settings.json", subdiv=f"{OUT}/subdiv.h5"
    output: f"{CONVS}/operators.h5"
    log: f"{CONVS}/logs/operators.log"
    benchmark: f"{CONVS}/benchmarks/operators.tsv"
    threads: 1
    resources: mem_mb=4000
    shell:
        "{PY:q} -m pipeline.operators {input.subdiv:q} {output:q} --settings {input.settings:q} --quiet "
        "2>&1 | tee {log:q}"


rule convs_train:
    input:
        settings=f"{CONVS}/{{task}}/settings.json", operators=f"{CONVS}/operators.h5",
        dataset=lambda w: convs_grid.task_dataset(w.scene, w.task),
    output: model=f"{CONVS_RUN}/model.pt", history=f"{CONVS_RUN}/train.h5"
    params: arch=lambda w: convs_grid.architecture(SETTINGS[w.scene], w.task, w.arch, w.conv)
    log: f"{CONVS_RUN}/logs/train.log"
    benchmark: f"{CONVS_RUN}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --arch {params.arch:q} --conv {wildcards.conv:q} --seed {wildcards.seed:q} "
        "--threads {threads} --quiet 2>&1 | tee {log:q}"


# Errors and timing only (common.smk: ERRORS_ONLY_EVALUATE).
rule convs_evaluate:
    input:
        settings=f"{CONVS}/{{task}}/settings.json", operators=f"{CONVS}/operators.h5",
        dataset=lambda w: convs_grid.task_dataset(w.scene, w.task), model=f"{CONVS_RUN}/model.pt",
    output:
        eval=f"{CONVS_RUN}/eval.h5", report=f"{CONVS_RUN}/report.md", export=directory(f"{CONVS_RUN}/export"),
    log: f"{CONVS_RUN}/logs/evaluate.log"
    benchmark: f"{CONVS_RUN}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell: ERRORS_ONLY_EVALUATE


rule convs:
    input: lambda w: convs_grid.stage_inputs(w.scene, SETTINGS[w.scene])
    output:
        table=f"{CONVS}/convs.h5", chart=f"{CONVS}/convs.png", report=f"{CONVS}/report.md",
        html=f"{CONVS}/report.html",
    params:
        runs=lambda w: convs_grid.stage_arguments(w.scene, SETTINGS[w.scene]), scene_report=f"{OUT}/report.md",
    log: f"{CONVS}/logs/convs.log"
    benchmark: f"{CONVS}/benchmarks/convs.tsv"
    threads: 1
    resources: mem_mb=2000
    shell:
        "{PY:q} -m experiments.convs {output.table:q} {output.chart:q} {output.report:q} {output.html:q} "
        "{params.runs:q} --scene-report {params.scene_report:q} 2>&1 | tee {log:q}"


# `results/<scene>/convs/` as a target (see the Snakefile's `results/<scene>/`), with and without the slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/convs/", f"results/{_scene}/convs"):
        rule:
            name: _target
            input: [f"results/{_scene}/convs/{name}" for name in ("convs.h5", "convs.png", "report.md", "report.html")]
