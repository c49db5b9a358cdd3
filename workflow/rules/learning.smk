# From simulations to a trained, evaluated network: operator tables of the high-res mesh, the dataset, training
# and evaluation (torch on the scene's device, with the job's threads).


rule operators:
    input: settings=f"{OUT}/settings.json", subdiv=f"{OUT}/subdiv.h5"
    output: f"{OUT}/operators.h5"
    log: log_of("operators")
    benchmark: benchmark_of("operators")
    threads: 1
    resources: mem_mb=4000
    shell:
        "{PY:q} -m pipeline.operators {input.subdiv:q} {output:q} --settings {input.settings:q} --quiet "
        "2>&1 | tee {log:q}"


rule dataset:
    input:
        settings=f"{OUT}/settings.json", sim_low=f"{OUT}/sim_low.h5", sim_high=f"{OUT}/sim_high.h5",
        subdiv=f"{OUT}/subdiv.h5", scene=f"{OUT}/scene.h5",
    output: f"{OUT}/dataset.h5"
    log: log_of("dataset")
    benchmark: benchmark_of("dataset")
    threads: 1
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.sim_low:q} {input.sim_high:q} {input.subdiv:q} {output:q} "
        "--scene {input.scene:q} --settings {input.settings:q} --quiet 2>&1 | tee {log:q}"


rule train:
    input: settings=f"{OUT}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5"
    output: model=f"{OUT}/model.pt", history=f"{OUT}/train.h5"
    log: log_of("train")
    benchmark: benchmark_of("train")
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule evaluate:
    input:
        settings=f"{OUT}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5",
        model=f"{OUT}/model.pt", scene=f"{OUT}/scene.h5",
    output:
        eval=f"{OUT}/eval.h5", report=f"{OUT}/report.md",
        renders=directory(f"{OUT}/renders"), export=directory(f"{OUT}/export"),
    log: log_of("evaluate")
    benchmark: benchmark_of("evaluate")
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
        "{output.report:q} --scene {input.scene:q} --renders {output.renders:q} --export {output.export:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"
