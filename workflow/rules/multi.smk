# One upsampling network for many garments (paper sec. 7, supplementary Table 3; docs/architecture.md,
# "Applications"): `results/multi/`. The scenes of the config's `multi.scenes` train one network with shared
# weights, each garment on its scene's own dataset.h5 and operators.h5 (results/<scene>/: none of a scene's stages
# runs again for it), with the scenes' network, training and device settings, which must agree. The network's view
# for each garment (results/multi/<scene>/model.pt) is evaluated by the same evaluate stage as the scene's own
# network, and a report sets the two side by side with Loop subdivision. Not part of `results/<scene>/`: `make run`
# does not grow. Only paths and the scene names (checked by the schema) reach a shell.
import experiments.multi.garments as multi_garments

MULTI = multi_garments.MULTI
MULTI_GARMENT = "results/multi/{scene}"
MULTI_SCENES = list(config.get("multi", {}).get("scenes", []))

if MULTI_SCENES:
    multi_garments.check_garment_names(MULTI_SCENES, SETTINGS)


def multi_products(wildcards=None):
    """What `results/multi/` stands for; scenes whose settings a shared network cannot serve are one error before
    any job runs."""
    multi_garments.check_shared_settings(MULTI_SCENES, SETTINGS)
    return multi_garments.multi_products(MULTI_SCENES)


if MULTI_SCENES:
    # The progress bar (epoch, running loss) is the job's log, as the scene's train rule's.
    rule multi_train:
        input:
            settings=multi_garments.scene_files(MULTI_SCENES, "settings.json"),
            datasets=multi_garments.scene_files(MULTI_SCENES, "dataset.h5"),
            operators=multi_garments.scene_files(MULTI_SCENES, "operators.h5"),
        output:
            model=f"{MULTI}/model.pt", history=f"{MULTI}/train.h5",
            views=[f"{MULTI}/{scene}/model.pt" for scene in MULTI_SCENES],
        params: garments=multi_garments.train_arguments(MULTI_SCENES)
        log: f"{MULTI}/logs/train.log"
        benchmark: f"{MULTI}/benchmarks/train.tsv"
        threads: workflow.cores
        resources: mem_mb=8000, gpu=device_gpus(MULTI_SCENES[0])
        shell:
            "{PY:q} -m experiments.multi train {output.model:q} {output.history:q} {params.garments:q} "
            "--threads {threads} 2>&1 | tee {log:q}"

    # The shared network on one garment's dataset: the scene's evaluate, with the garment's view of the network
    # and the scene's evaluation settings (the multi report has the training curve).
    rule multi_evaluate:
        input:
            settings=f"{OUT}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5",
            model=f"{MULTI_GARMENT}/model.pt",
        output:
            eval=f"{MULTI_GARMENT}/eval.h5", report=f"{MULTI_GARMENT}/report.md",
            html=f"{MULTI_GARMENT}/report.html", renders=directory(f"{MULTI_GARMENT}/renders"),
            videos=directory(f"{MULTI_GARMENT}/videos"), export=directory(f"{MULTI_GARMENT}/export"),
        wildcard_constraints: scene=workflow_paths.one_of(MULTI_SCENES)
        log: f"{MULTI_GARMENT}/logs/evaluate.log"
        benchmark: f"{MULTI_GARMENT}/benchmarks/evaluate.tsv"
        threads: workflow.cores
        resources: mem_mb=8000, gpu=gpus_on_device
        shell:
            "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
            "{output.report:q} --html {output.html:q} --scene {input.dataset:q} --renders {output.renders:q} "
            "--videos {output.videos:q} --export {output.export:q} --settings {input.settings:q} "
            "--threads {threads} --quiet 2>&1 | tee {log:q}"

    rule multi_report:
        input:
            model=f"{MULTI}/model.pt", history=f"{MULTI}/train.h5",
            shared=[f"{MULTI}/{scene}/eval.h5" for scene in MULTI_SCENES],
            own=multi_garments.scene_files(MULTI_SCENES, "eval.h5"),
        output: table=f"{MULTI}/multi.h5", curve=f"{MULTI}/training_curve.png", report=f"{MULTI}/report.md"
        params: garments=multi_garments.report_arguments(MULTI_SCENES)
        log: f"{MULTI}/logs/report.log"
        benchmark: f"{MULTI}/benchmarks/report.tsv"
        threads: 1
        resources: mem_mb=2000
        shell:
            "{PY:q} -m experiments.multi.report {output.table:q} {output.curve:q} {output.report:q} "
            "--model {input.model:q} --train-log {input.history:q} {params.garments:q} 2>&1 | tee {log:q}"

    # `results/multi/` as a target (see the Snakefile's `results/<scene>/`), with and without the trailing slash;
    # what it stands for is resolved only when asked for.
    for _target in (f"{MULTI}/", MULTI):
        rule:
            name: _target
            input: multi_products
