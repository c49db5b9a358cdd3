# From simulations to a trained, evaluated network: operator tables of the high-res mesh, the dataset, training
# and evaluation (torch on the scene's device, with the job's threads).


# On the subdivided cloth (subdiv.h5), or a hand scene's skin (hand.h5).
rule operators:
    input: settings=f"{OUT}/settings.json", mesh=operators_mesh
    output: f"{OUT}/operators.h5"
    log: log_of("operators")
    benchmark: benchmark_of("operators")
    threads: 1
    resources: mem_mb=4000
    shell:
        "{PY:q} -m pipeline.operators {input.mesh:q} {output:q} --settings {input.settings:q} --quiet "
        "2>&1 | tee {log:q}"


# The dataset gathers every sequence of the scene (their folders, in order).
rule dataset:
    input:
        settings=f"{OUT}/simulation.json", subdiv=f"{OUT}/subdiv.h5", scenes=sequence_files("scene.h5"),
        sim_low=sequence_files("sim_low.h5"), sim_high=sequence_files("sim_high.h5"),
    output: f"{OUT}/dataset.h5"
    params: sequences=sequence_folders
    log: log_of("dataset")
    benchmark: benchmark_of("dataset")
    threads: workflow.cores
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# Without --quiet: its progress bar (epoch, running loss) is what `make run` shows while it trains. With
# `training.ranks: N` the job runs N processes under torchrun (one GPU each on CUDA), the job's threads shared out.
rule train:
    input: settings=f"{OUT}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5"
    output: model=f"{OUT}/model.pt", history=f"{OUT}/train.h5"
    params: launcher=recipe_train_launcher, threads=recipe_train_threads
    log: log_of("train")
    benchmark: benchmark_of("train")
    threads: workflow.cores
    resources: mem_mb=8000, gpu=recipe_train_gpus
    # Ahead of the study's, trade-off's and applications' jobs when they wait for the same GPU slots (`--resources
    # gpu=N`): the scene's own model and report are what the others compare against. (On the H100 the trade-off's
    # evaluations took every slot first and the lease ended before the scene's report was made.)
    priority: 1
    shell:
        "{PY:q} {params.launcher:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} "
        "{output.history:q} --settings {input.settings:q} --threads {params.threads} 2>&1 | tee {log:q}"


# dataset.h5 carries each frame's mannequin under scene.h5's names, so it is also the --scene the renders draw
# the body from (a garment scene's frames come from many sequences' scene files). The videos are a folder: their
# suffix (.mp4, or .gif without an encoder) is known only once encoded.
rule evaluate:
    input:
        settings=f"{OUT}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5",
        model=f"{OUT}/model.pt", train_log=f"{OUT}/train.h5",
    output:
        eval=f"{OUT}/eval.h5", report=f"{OUT}/report.md", html=f"{OUT}/report.html",
        renders=directory(f"{OUT}/renders"), videos=directory(f"{OUT}/videos"), export=directory(f"{OUT}/export"),
    log: log_of("evaluate")
    benchmark: benchmark_of("evaluate")
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    priority: 1     # as train's
    # The scene's other reports, made by their own targets (the links work once those are built).
    params: tradeoff=f"{OUT}/tradeoff/report.md", study=f"{OUT}/study/report.md", convs=f"{OUT}/convs/report.md"
    shell:
        "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
        "{output.report:q} --html {output.html:q} --train-log {input.train_log:q} --scene {input.dataset:q} "
        "--renders {output.renders:q} --videos {output.videos:q} --export {output.export:q} "
        "--tradeoff-report {params.tradeoff:q} --study-report {params.study:q} --convs-report {params.convs:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# On request only (`snakemake results/<scene>/deploy`), not part of `results/<scene>/`: the trained model as a
# self-contained upsampler that runs with torch and numpy alone (deploy/README.md); a scene on CUDA also gets the
# fused bf16 network's program and the package of its Triton operators, checked on the job's GPU.
rule export_model:
    input:
        settings=f"{OUT}/settings.json", model=f"{OUT}/model.pt", operators=f"{OUT}/operators.h5",
        subdiv=f"{OUT}/subdiv.h5",
    output: directory(f"{OUT}/deploy")
    log: log_of("export_model")
    benchmark: benchmark_of("export_model")
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.export_model {input.model:q} {input.operators:q} {input.subdiv:q} {output:q} "
        "--settings {input.settings:q} --quiet 2>&1 | tee {log:q}"
