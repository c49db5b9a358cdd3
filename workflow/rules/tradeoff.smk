# The speed-accuracy trade (issue 14, docs/performance.md): `results/<scene>/tradeoff/`. Every row of the table is
# a way to get the high-res cloth, scored against the scene's high-res runs and timed beside them.
# * Low-res budgets (`tradeoff.substeps`, plus those of `tradeoff.matched`; each n substeps at the scene's iterations,
#   folder s<n>/, or [n, i], folder s<n>x<i>/): for each but the scene's own the scene's sequences are re-simulated
#   at low resolution with that solver budget, as the scene's runs were: one job per sequence (`shard: 1`) or a
#   batch job per shard; a folder per sequence beside that run links the sequence's scene.h5 and high-res run
#   (the ground truth stays the scene's), so the dataset stage gathers them unchanged (same sequences, same seeded
#   split). The scene's own budget reuses the scene's runs and dataset.h5. The budgets' low-res ms are not these
#   runs': the stage times each budget's solver itself (below).
# * Networks fed each budget's inputs (errors only; eval.h5 keeps its own timing for its report): the scene's
#   trained network; the scene's conv at each width of `tradeoff.widths` (folder w<width>/, the scene's settings
#   with that width and `tradeoff.epochs`), trained on the scene's dataset.h5; and for each budget of
#   `tradeoff.matched` other than the scene's own, the scene's network recipe trained on that budget's own dataset
#   (s<budget>/matched/): does matching the training input to the deployed solver budget remove the input shift? -
#   and the same recipe at each width of `tradeoff.matched_widths` (s<budget>/matched_w<width>/): the cheapest
#   accurate learned path.
# * High-res runs beside the scene's (folder h<substeps>x<iterations>_<schedule>/): each [substeps, iterations] of
#   `tradeoff.high_res_budgets` with the scene's harmonic schedule, and the scene's budget with each schedule of
#   `tradeoff.harmonic_every`, the scene's own run (the reference) left out; each held to the scene's low-res run,
#   simulated as the scene's high-res runs were (per sequence, or a batch job per shard); a sharded scene also runs
#   the first sequence alone for each, whose ms is the row's.
# Then one table, plot and report (experiments.tradeoff), which times both sides of the speedup itself, one after
# another on the device in its one job: the reference (the high-res solver at the scene's budget, free: body and
# self collision, not held to a low-res run, the paper's reference) and each budget's low-res solver, on the
# scene's first sequence stepped alone, then Loop subdivision and every network (fp32 and, on CUDA, the fused bf16
# network; the evaluations may have shared the device with other jobs). None of this is part of `results/<scene>/`:
# `make run` does not grow. Only paths and the grid's numbers and schedule names (integers and an enum, checked by
# the schema) reach a shell, quoted.

import os

import experiments.tradeoff.grid as tradeoff_grid

TRADEOFF = "results/{scene}/tradeoff"
TRADEOFF_POINT = "results/{scene}/tradeoff/s{budget}"
TRADEOFF_SEQ = "results/{scene}/tradeoff/s{budget}/sequences/{seq}"
TRADEOFF_NET = "results/{scene}/tradeoff/w{width}"       # a smaller network: settings.json, model.pt, train.h5
TRADEOFF_MATCHED = "results/{scene}/tradeoff/s{budget}/matched"    # trained on the budget's inputs: model.pt
TRADEOFF_MATCHED_NET = "results/{scene}/tradeoff/s{budget}/matched_w{width}"    # the same at another width
TRADEOFF_EVAL = "results/{scene}/tradeoff/s{budget}/{net}"     # a network on a budget's inputs: eval.h5, ...
TRADEOFF_HIGH = "results/{scene}/tradeoff/h{hsubsteps}x{hiterations}_{schedule}"   # simulation.json, sequences/
# A matched network's training: the scene's recipe, on its ranks (common.smk's recipe_train_*).
MATCHED_TRAIN = ("{PY:q} {params.launcher:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} "
                 "{output.history:q} --settings {input.settings:q} --threads {params.threads} --quiet 2>&1 | "
                 "tee {log:q}")

# One sequence's high-res run held to the scene's low-res run of it (the rule's settings say which budget). A
# library's window starts, at every budget, from the scene's settle run of its level (`params.settled`): the budgets
# differ in how the windows are stepped, not in the cloth they start from.
HIGH_RES_ALONE = ("{PY:q} -m pipeline.simulate high {input.settings:q} {input.scene:q} {input.subdiv:q} "
                  "{input.sim_low:q} {output:q} {params.settled:q} --quiet 2>&1 | tee {log:q}")

wildcard_constraints:
    budget="[1-9][0-9]*(x[1-9][0-9]*)?",
    width="[0-9]+(\\.[0-9]+)?(e-[0-9]+)?",
    net="scene|(matched_)?w[0-9]+(\\.[0-9]+)?(e-[0-9]+)?|matched",
    hsubsteps="[1-9][0-9]*",
    hiterations="[1-9][0-9]*",
    schedule="iteration|substep",


# The grid's logic (budgets, high-res runs, folders, settings overlays, the stage's arguments) is
# experiments.tradeoff.grid's; these feed it a scene's settings and sequences.
def first_sequence_file(name):
    """The scene's first sequence's file `name`: what a timing run simulates alone."""
    return lambda w: f"results/{w.scene}/sequences/{SEQUENCES[w.scene][0]}/{name}"


def first_sequence(wildcards):
    return SEQUENCES[wildcards.scene][:1]


def tradeoff_sequence_files(name):
    return lambda w: [f"{folder}/{name}" for folder in tradeoff_sequence_folders(w)]


def tradeoff_sequence_folders(wildcards):
    return tradeoff_grid.point_sequence_folders(wildcards.scene, wildcards.budget, SEQUENCES[wildcards.scene])


rule tradeoff_settings:
    output: f"{TRADEOFF_POINT}/settings.json"
    params: settings=lambda w: tradeoff_grid.point_settings(SETTINGS[w.scene], w.budget)
    log: f"{TRADEOFF_POINT}/logs/settings.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with the low-res budget {wildcards.budget}", file=f)


rule tradeoff_simulation_settings:
    output: f"{TRADEOFF_POINT}/simulation.json"
    params: settings=lambda w: tradeoff_grid.point_simulation(SETTINGS[w.scene], w.budget)
    log: f"{TRADEOFF_POINT}/logs/simulation_settings.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/simulation_settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's simulation.json with the low-res budget {wildcards.budget}", file=f)


rule tradeoff_simulate_low:
    input: settings=f"{TRADEOFF_POINT}/simulation.json", scene=f"{SEQ}/scene.h5", settled=settled_runs("low")
    output: f"{TRADEOFF_SEQ}/sim_low.h5"
    wildcard_constraints: scene=UNSHARDED
    params: settled=settled_flag("low")
    log: f"{TRADEOFF_POINT}/logs/{{seq}}/simulate_low.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/{{seq}}/simulate_low.tsv"
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} {params.settled:q} --quiet "
        "2>&1 | tee {log:q}"


rule tradeoff_high_settings:
    output: f"{TRADEOFF_HIGH}/simulation.json"
    params:
        settings=lambda w: tradeoff_grid.high_res_simulation(SETTINGS[w.scene],
                                                             (w.hsubsteps, w.hiterations, w.schedule))
    log: f"{TRADEOFF_HIGH}/logs/settings.log"
    benchmark: f"{TRADEOFF_HIGH}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with solver {wildcards.hsubsteps} substeps x "
                  f"{wildcards.hiterations} iterations, harmonic projection every {wildcards.schedule}", file=f)


# A high-res run held to the scene's own low-res run of the sequence (only the high-res solver's budget or schedule
# differs from the scene's high-res run).
rule tradeoff_simulate_high:
    input:
        settings=f"{TRADEOFF_HIGH}/simulation.json", scene=f"{SEQ}/scene.h5", subdiv=f"{OUT}/subdiv.h5",
        sim_low=f"{SEQ}/sim_low.h5", settled=settled_runs("high"),
    output: f"{TRADEOFF_HIGH}/sequences/{{seq}}/sim_high.h5"
    wildcard_constraints: scene=UNSHARDED
    params: settled=settled_flag("high")
    log: f"{TRADEOFF_HIGH}/logs/{{seq}}/simulate_high.log"
    benchmark: f"{TRADEOFF_HIGH}/benchmarks/{{seq}}/simulate_high.tsv"
    threads: 1
    resources: mem_mb=8000, gpu=gpus_on_device
    shell: HIGH_RES_ALONE


# The first sequence alone at high resolution, one solver world, held to the scene's low-res run of it: a sharded
# scene's high-res ms per frame of each high-res run beside the scene's (a batch's ms divided by its sequences would
# flatter the high-res rows on a GPU).
rule tradeoff_timing_high:
    input:
        settings=f"{TRADEOFF_HIGH}/simulation.json", subdiv=f"{OUT}/subdiv.h5",
        scene=first_sequence_file("scene.h5"), sim_low=first_sequence_file("sim_low.h5"),
        settled=settled_runs("high", first_sequence),
    output: f"{TRADEOFF_HIGH}/timing/sim_high.h5"
    params: settled=settled_flag("high", first_sequence)
    log: f"{TRADEOFF_HIGH}/logs/timing_high.log"
    benchmark: f"{TRADEOFF_HIGH}/benchmarks/timing_high.tsv"
    threads: 1
    resources: mem_mb=8000, gpu=gpus_on_device
    shell: HIGH_RES_ALONE


# Sharded scenes: a rule per shard steps its sequences together at every low-res budget (the `budget` wildcard)
# and every high-res run (its folder's wildcards), named tradeoff_simulate_low_batch_<scene>_<k> and
# tradeoff_simulate_high_batch_<scene>_<k>, as simulate.smk's; every path but the budget's folder is a literal.
for _scene, _shards in ((s, sequence_shards(SETTINGS[s])) for s in SETTINGS if SETTINGS[s]["shard"] > 1):
    for _k, _names in enumerate(_shards):
        _point, _out = f"results/{_scene}/tradeoff/s{{budget}}", f"results/{_scene}"
        _high = f"results/{_scene}/tradeoff/h{{hsubsteps}}x{{hiterations}}_{{schedule}}"
        _gpu = device_gpus(_scene)

        rule:
            name: workflow_paths.batch_rule_name("tradeoff_simulate_low", _scene, _k)
            input:
                settings=f"{_point}/simulation.json",
                scenes=[f"{_out}/sequences/{n}/scene.h5" for n in _names],
                settled=workflow_paths.settled_runs(_scene, _names, "low"),
            output: [f"{_point}/sequences/{n}/sim_low.h5" for n in _names]
            params:
                files=lambda w, names=_names, scene=_scene: [
                    p for n in names for p in (f"results/{scene}/sequences/{n}/scene.h5",
                                               f"results/{scene}/tradeoff/s{w.budget}/sequences/{n}/sim_low.h5")],
                settled=workflow_paths.settled_flag(_scene, _names, "low"),
            log: f"{_point}/logs/shard_{_k:03d}/simulate_low.log"
            benchmark: f"{_point}/benchmarks/shard_{_k:03d}/simulate_low.tsv"
            threads: 1
            resources: mem_mb=4000 + 500 * len(_names), gpu=_gpu
            shell:
                "{PY:q} -m pipeline.simulate low {input.settings:q} {params.files:q} {params.settled:q} --quiet 2>&1 "
                "| tee {log:q}"

        rule:
            name: workflow_paths.batch_rule_name("tradeoff_simulate_high", _scene, _k)
            input:
                settings=f"{_high}/simulation.json", subdiv=f"{_out}/subdiv.h5",
                scenes=[f"{_out}/sequences/{n}/scene.h5" for n in _names],
                sim_low=[f"{_out}/sequences/{n}/sim_low.h5" for n in _names],
                settled=workflow_paths.settled_runs(_scene, _names, "high"),
            output: [f"{_high}/sequences/{n}/sim_high.h5" for n in _names]
            params:
                files=lambda w, names=_names, scene=_scene: [
                    p for n in names for p in (
                        f"results/{scene}/sequences/{n}/scene.h5", f"results/{scene}/subdiv.h5",
                        f"results/{scene}/sequences/{n}/sim_low.h5",
                        tradeoff_grid.high_res_file(scene, (w.hsubsteps, w.hiterations, w.schedule), n))],
                settled=workflow_paths.settled_flag(_scene, _names, "high"),
            log: f"{_high}/logs/shard_{_k:03d}/simulate_high.log"
            benchmark: f"{_high}/benchmarks/shard_{_k:03d}/simulate_high.tsv"
            threads: high_batch_threads(_scene, len(_names))
            resources: mem_mb=8000 + 2000 * len(_names), gpu=_gpu
            shell:
                "{PY:q} -m pipeline.simulate high {input.settings:q} {params.files:q} {params.settled:q} "
                "--threads {threads} --quiet 2>&1 | tee {log:q}"


# The sequence's own scene.h5 and high-res run, linked (relative) into the budget's sequence folder.
rule tradeoff_sequence_links:
    input: scene=f"{SEQ}/scene.h5", sim_high=f"{SEQ}/sim_high.h5"
    output: scene=f"{TRADEOFF_SEQ}/scene.h5", sim_high=f"{TRADEOFF_SEQ}/sim_high.h5"
    log: f"{TRADEOFF_POINT}/logs/{{seq}}/links.log"
    localrule: True
    threads: 1
    resources: mem_mb=100
    run:
        for source, link in ((input.scene, output.scene), (input.sim_high, output.sim_high)):
            os.makedirs(os.path.dirname(link), exist_ok=True)
            if os.path.lexists(link):    # a dangling link: Snakemake, which follows links, does not see it to remove
                os.remove(link)
            os.symlink(os.path.relpath(source, os.path.dirname(link)), link)
        with open(log[0], "w") as f:
            print(f"{output.scene}, {output.sim_high}: links to {input.scene}, {input.sim_high}", file=f)


rule tradeoff_dataset:
    input:
        settings=f"{TRADEOFF_POINT}/simulation.json", subdiv=f"{OUT}/subdiv.h5",
        scenes=tradeoff_sequence_files("scene.h5"), sim_low=tradeoff_sequence_files("sim_low.h5"),
        sim_high=tradeoff_sequence_files("sim_high.h5"),
    output: f"{TRADEOFF_POINT}/dataset.h5"
    params: sequences=tradeoff_sequence_folders
    log: f"{TRADEOFF_POINT}/logs/dataset.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/dataset.tsv"
    threads: workflow.cores
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule tradeoff_network_settings:
    output: f"{TRADEOFF_NET}/settings.json"
    params: settings=lambda w: tradeoff_grid.network_settings(SETTINGS[w.scene], w.width)
    log: f"{TRADEOFF_NET}/logs/settings.log"
    benchmark: f"{TRADEOFF_NET}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with network.width {wildcards.width}", file=f)


rule tradeoff_train:
    input: settings=f"{TRADEOFF_NET}/settings.json", dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5"
    output: model=f"{TRADEOFF_NET}/model.pt", history=f"{TRADEOFF_NET}/train.h5"
    log: f"{TRADEOFF_NET}/logs/train.log"
    benchmark: f"{TRADEOFF_NET}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.train {input.dataset:q} {input.operators:q} {output.model:q} {output.history:q} "
        "--settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


# The scene's network recipe (its settings, which the budget's settings.json keeps but for the low-res solver budget the
# training never reads) trained on the budget's own dataset.
rule tradeoff_train_matched:
    input:
        settings=f"{TRADEOFF_POINT}/settings.json", dataset=f"{TRADEOFF_POINT}/dataset.h5",
        operators=f"{OUT}/operators.h5",
    output: model=f"{TRADEOFF_MATCHED}/model.pt", history=f"{TRADEOFF_MATCHED}/train.h5"
    params: launcher=recipe_train_launcher, threads=recipe_train_threads
    log: f"{TRADEOFF_MATCHED}/logs/train.log"
    benchmark: f"{TRADEOFF_MATCHED}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=recipe_train_gpus
    shell: MATCHED_TRAIN


rule tradeoff_matched_settings:
    output: f"{TRADEOFF_MATCHED_NET}/settings.json"
    params: settings=lambda w: tradeoff_grid.matched_settings(SETTINGS[w.scene], w.budget, w.width)
    log: f"{TRADEOFF_MATCHED_NET}/logs/settings.log"
    benchmark: f"{TRADEOFF_MATCHED_NET}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the budget's settings with network.width {wildcards.width}", file=f)


# The scene's recipe at another width, trained on the budget's own dataset.
rule tradeoff_train_matched_width:
    input:
        settings=f"{TRADEOFF_MATCHED_NET}/settings.json", dataset=f"{TRADEOFF_POINT}/dataset.h5",
        operators=f"{OUT}/operators.h5",
    output: model=f"{TRADEOFF_MATCHED_NET}/model.pt", history=f"{TRADEOFF_MATCHED_NET}/train.h5"
    params: launcher=recipe_train_launcher, threads=recipe_train_threads
    log: f"{TRADEOFF_MATCHED_NET}/logs/train.log"
    benchmark: f"{TRADEOFF_MATCHED_NET}/benchmarks/train.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=recipe_train_gpus
    shell: MATCHED_TRAIN


# A network on a budget's inputs (`net`: `scene`, the scene's own model.pt; `matched`; `matched_w<width>`; or
# w<width>): errors and timing only (no renders, one exported frame, no predicted positions in eval.h5).
rule tradeoff_evaluate:
    input:
        settings=f"{TRADEOFF_POINT}/settings.json",
        dataset=lambda w: tradeoff_grid.point_dataset(w.scene, SETTINGS[w.scene], w.budget),
        operators=f"{OUT}/operators.h5", model=lambda w: tradeoff_grid.network_model(w.scene, w.budget, w.net),
    output:
        eval=f"{TRADEOFF_EVAL}/eval.h5", report=f"{TRADEOFF_EVAL}/report.md",
        export=directory(f"{TRADEOFF_EVAL}/export"),
    log: f"{TRADEOFF_EVAL}/logs/evaluate.log"
    benchmark: f"{TRADEOFF_EVAL}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell: ERRORS_ONLY_EVALUATE


rule tradeoff:
    input:
        settings=f"{OUT}/settings.json", subdiv=f"{OUT}/subdiv.h5", dataset=f"{OUT}/dataset.h5",
        operators=f"{OUT}/operators.h5", sim_high=sequence_files("sim_high.h5"),
        points=lambda w: tradeoff_grid.stage_inputs(w.scene, SETTINGS[w.scene], SEQUENCES[w.scene]),
    output: table=f"{TRADEOFF}/tradeoff.h5", plot=f"{TRADEOFF}/pareto.png", report=f"{TRADEOFF}/report.md"
    params: grid=lambda w: tradeoff_grid.stage_arguments(w.scene, SETTINGS[w.scene], SEQUENCES[w.scene])
    log: f"{TRADEOFF}/logs/tradeoff.log"
    benchmark: f"{TRADEOFF}/benchmarks/tradeoff.tsv"
    threads: workflow.cores
    # The dataset's frames on the device, to time the networks; its GPU whole: both sides of every speedup are
    # timed here, with no other job's kernels beside them.
    resources: mem_mb=16000, gpu=whole_gpus_on_device
    shell:
        "{PY:q} -m experiments.tradeoff {input.subdiv:q} {output.table:q} {output.plot:q} {output.report:q} "
        "--sim-high {input.sim_high:q} --dataset {input.dataset:q} --operators {input.operators:q} {params.grid:q} "
        "--settings {input.settings:q} "
        "--threads {threads} 2>&1 | tee {log:q}"


# `results/<scene>/tradeoff/` as a target (see the Snakefile's `results/<scene>/`), with and without the slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/tradeoff/", f"results/{_scene}/tradeoff"):
        rule:
            name: _target
            input: [f"results/{_scene}/tradeoff/{name}" for name in ("tradeoff.h5", "pareto.png", "report.md")]
