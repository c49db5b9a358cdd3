# The speed-accuracy trade (issue 14, docs/performance.md): `results/<scene>/tradeoff/`. For each low-res budget
# n of `tradeoff.substeps` the scene's sequences are re-simulated at low resolution with n substeps (the scene's
# iterations), as the scene's runs were: one job per sequence (`shard: 1`, whose solver timing is one sequence's),
# or a batch job per shard plus a timing run of the first sequence alone (timing/sim_low.h5: a batch's ms on a
# GPU is about one sequence's, so divided by its sequences it would flatter the learned path); a folder per sequence
# beside that run links the sequence's scene.h5 and high-res run (the ground truth stays the scene's), so the
# dataset stage gathers them unchanged (same sequences, same seeded split); the scene's trained network is
# evaluated on that dataset (errors and deployment-path timing only). Smaller networks, the scene's conv at each
# width of `tradeoff.widths` (folder w<width>/, its settings.json the scene's with that width and
# `tradeoff.epochs`), are trained on the scene's own dataset.h5 and evaluated on each budget's the same way.
# Then one table, plot and report.
# None of this is part of `results/<scene>/`: `make run` does not grow. Only paths reach a shell.

TRADEOFF = "results/{scene}/tradeoff"
TRADEOFF_POINT = "results/{scene}/tradeoff/s{substeps}"
TRADEOFF_SEQ = "results/{scene}/tradeoff/s{substeps}/sequences/{seq}"
TRADEOFF_NET = "results/{scene}/tradeoff/w{width}"       # a smaller network: settings.json, model.pt, train.h5
TRADEOFF_EVAL = "results/{scene}/tradeoff/s{substeps}/{net}"     # a network on a budget's inputs: eval.h5, ...

wildcard_constraints:
    substeps="[1-9][0-9]*",
    width="[0-9]+(\\.[0-9]+)?(e-[0-9]+)?",
    net="scene|w[0-9]+(\\.[0-9]+)?(e-[0-9]+)?",


def width_folder(width):
    """The folder name of a width: `:g`, so that the config's 0.5 and the wildcard's '0.5' agree."""
    return f"w{float(width):g}"


def tradeoff_point_settings(settings, substeps):
    """settings.json of budget `substeps`: the scene's, with that many low-res substeps."""
    shared = shared_settings(settings)
    return {**shared, "solver": {**shared["solver"], "substeps": int(substeps)}}


def tradeoff_network_settings(settings, width):
    """settings.json of the network of `width`: the scene's, with that width and the tradeoff's epochs."""
    shared = shared_settings(settings)
    return {**shared, "network": {**shared["network"], "width": float(width)},
            "training": {**shared["training"], "epochs": settings["tradeoff"]["epochs"]}}


def tradeoff_evals(scene, n):
    """Every eval.h5 of budget `n`: the scene's network's, then each smaller one's."""
    nets = ["scene", *[width_folder(w) for w in SETTINGS[scene]["tradeoff"]["widths"]]]
    return [f"results/{scene}/tradeoff/s{n}/{net}/eval.h5" for net in nets]


def tradeoff_model(wildcards):
    if wildcards.net == "scene":
        return f"results/{wildcards.scene}/model.pt"
    return f"results/{wildcards.scene}/tradeoff/{wildcards.net}/model.pt"


def tradeoff_sequence_files(name):
    return lambda w: [f"results/{w.scene}/tradeoff/s{w.substeps}/sequences/{seq}/{name}" for seq in SEQUENCES[w.scene]]


def tradeoff_sequence_folders(wildcards):
    return [f"results/{wildcards.scene}/tradeoff/s{wildcards.substeps}/sequences/{seq}"
            for seq in SEQUENCES[wildcards.scene]]


def tradeoff_low_runs(scene, n):
    return [f"results/{scene}/tradeoff/s{n}/sequences/{seq}/sim_low.h5" for seq in SEQUENCES[scene]]


def tradeoff_timed_runs(scene, n):
    """The runs whose solver timing is the budget's low-res ms: each sequence's own job, or the timing run."""
    if SETTINGS[scene]["shard"] == 1:
        return tradeoff_low_runs(scene, n)
    return [f"results/{scene}/tradeoff/s{n}/timing/sim_low.h5"]


def tradeoff_point_arguments(wildcards):
    """`--point N SIM_LOW.h5 ...` and `--eval N EVAL.h5` for each budget and network."""
    scene = wildcards.scene
    return [str(x) for n in SETTINGS[scene]["tradeoff"]["substeps"]
            for x in ("--point", n, *tradeoff_timed_runs(scene, n),
                      *[y for path in tradeoff_evals(scene, n) for y in ("--eval", n, path)])]


def tradeoff_inputs(wildcards):
    scene = wildcards.scene
    return [path for n in SETTINGS[scene]["tradeoff"]["substeps"]
            for path in (*tradeoff_evals(scene, n), *tradeoff_timed_runs(scene, n))]


rule tradeoff_settings:
    output: f"{TRADEOFF_POINT}/settings.json"
    params: settings=lambda w: tradeoff_point_settings(SETTINGS[w.scene], w.substeps)
    log: f"{TRADEOFF_POINT}/logs/settings.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/settings.tsv"
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: the scene's settings with solver.substeps {wildcards.substeps}", file=f)


rule tradeoff_simulate_low:
    input: settings=f"{TRADEOFF_POINT}/settings.json", scene=f"{SEQ}/scene.h5"
    output: f"{TRADEOFF_SEQ}/sim_low.h5"
    wildcard_constraints: scene=UNSHARDED
    log: f"{TRADEOFF_POINT}/logs/{{seq}}/simulate_low.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/{{seq}}/simulate_low.tsv"
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} --quiet 2>&1 | tee {log:q}"


# The first sequence alone, one solver world: the low-res timing of a sharded scene's budget.
rule tradeoff_timing_low:
    input:
        settings=f"{TRADEOFF_POINT}/settings.json",
        scene=lambda w: f"results/{w.scene}/sequences/{SEQUENCES[w.scene][0]}/scene.h5",
    output: f"{TRADEOFF_POINT}/timing/sim_low.h5"
    log: f"{TRADEOFF_POINT}/logs/timing_low.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/timing_low.tsv"
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} --quiet 2>&1 | tee {log:q}"


# Sharded scenes: a rule per shard steps its sequences together at every budget (the `substeps` wildcard), named
# tradeoff_simulate_low_batch_<scene>_<k>, as simulate.smk's; every path but the budget's folder is a literal.
for _scene, _shards in ((s, sequence_shards(SETTINGS[s])) for s in SETTINGS if SETTINGS[s]["shard"] > 1):
    for _k, _names in enumerate(_shards):
        _point = f"results/{_scene}/tradeoff/s{{substeps}}"

        rule:
            name: batch_rule_name("tradeoff_simulate_low", _scene, _k)
            input:
                settings=f"{_point}/settings.json",
                scenes=[f"results/{_scene}/sequences/{n}/scene.h5" for n in _names]
            output: [f"{_point}/sequences/{n}/sim_low.h5" for n in _names]
            params:
                files=lambda w, names=_names, scene=_scene: [
                    p for n in names for p in (f"results/{scene}/sequences/{n}/scene.h5",
                                               f"results/{scene}/tradeoff/s{w.substeps}/sequences/{n}/sim_low.h5")]
            log: f"{_point}/logs/shard_{_k:03d}/simulate_low.log"
            benchmark: f"{_point}/benchmarks/shard_{_k:03d}/simulate_low.tsv"
            threads: 1
            resources: mem_mb=4000 + 500 * len(_names), gpu=int(SETTINGS[_scene]["device"].startswith("cuda"))
            shell: "{PY:q} -m pipeline.simulate low {input.settings:q} {params.files:q} --quiet 2>&1 | tee {log:q}"


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
            os.symlink(os.path.relpath(source, os.path.dirname(link)), link)
        with open(log[0], "w") as f:
            print(f"{output.scene}, {output.sim_high}: links to {input.scene}, {input.sim_high}", file=f)


rule tradeoff_dataset:
    input:
        settings=f"{TRADEOFF_POINT}/settings.json", subdiv=f"{OUT}/subdiv.h5",
        scenes=tradeoff_sequence_files("scene.h5"), sim_low=tradeoff_sequence_files("sim_low.h5"),
        sim_high=tradeoff_sequence_files("sim_high.h5"),
    output: f"{TRADEOFF_POINT}/dataset.h5"
    params: sequences=tradeoff_sequence_folders
    log: f"{TRADEOFF_POINT}/logs/dataset.log"
    benchmark: f"{TRADEOFF_POINT}/benchmarks/dataset.tsv"
    threads: 1
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.dataset {input.subdiv:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --quiet 2>&1 | tee {log:q}"


rule tradeoff_network_settings:
    output: f"{TRADEOFF_NET}/settings.json"
    params: settings=lambda w: tradeoff_network_settings(SETTINGS[w.scene], w.width)
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


# A network on a budget's inputs (`net`: `scene`, the scene's own model.pt, or w<width>): errors and timing only
# (no renders, one exported frame).
rule tradeoff_evaluate:
    input:
        settings=f"{TRADEOFF_POINT}/settings.json", dataset=f"{TRADEOFF_POINT}/dataset.h5",
        operators=f"{OUT}/operators.h5", model=tradeoff_model,
    output:
        eval=f"{TRADEOFF_EVAL}/eval.h5", report=f"{TRADEOFF_EVAL}/report.md",
        export=directory(f"{TRADEOFF_EVAL}/export"),
    log: f"{TRADEOFF_EVAL}/logs/evaluate.log"
    benchmark: f"{TRADEOFF_EVAL}/benchmarks/evaluate.tsv"
    threads: workflow.cores
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.evaluate {input.dataset:q} {input.operators:q} {input.model:q} {output.eval:q} "
        "{output.report:q} --export {output.export:q} --render-frames 0 --video-frames 0 "
        "--export-frames 1 --settings {input.settings:q} --threads {threads} --quiet 2>&1 | tee {log:q}"


rule tradeoff:
    input:
        settings=f"{OUT}/settings.json", subdiv=f"{OUT}/subdiv.h5", sim_high=sequence_files("sim_high.h5"),
        points=tradeoff_inputs,
    output: table=f"{TRADEOFF}/tradeoff.h5", plot=f"{TRADEOFF}/pareto.png", report=f"{TRADEOFF}/report.md"
    params: points=tradeoff_point_arguments
    log: f"{TRADEOFF}/logs/tradeoff.log"
    benchmark: f"{TRADEOFF}/benchmarks/tradeoff.tsv"
    threads: workflow.cores
    resources: mem_mb=2000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.tradeoff {input.subdiv:q} {output.table:q} {output.plot:q} {output.report:q} "
        "--sim-high {input.sim_high:q} {params.points:q} --settings {input.settings:q} --threads {threads} "
        "2>&1 | tee {log:q}"


# `results/<scene>/tradeoff/` as a target (see the Snakefile's `results/<scene>/`), with and without the slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/tradeoff/", f"results/{_scene}/tradeoff"):
        rule:
            name: _target
            input: [f"results/{_scene}/tradeoff/{name}" for name in ("tradeoff.h5", "pareto.png", "report.md")]
