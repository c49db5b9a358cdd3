# The XPBD runs of each sequence on the scene's device: low-res, then high-res held to it by the harmonic
# constraint. A scene with `shard: 1` (the CPU profile) has one job per sequence, run side by side on the cores;
# a scene with a larger shard has one job per shard of sequences (scenes.sequences.sequence_shards), which steps
# them together as one batch of solver worlds: on a GPU a batch costs about what one sequence does.

# A library's windows start from the cloth settled once at rest (results/<scene>/settle/: settle_scene in
# scene.smk, then its runs here), each job given that run of its level (`--settled`).
#
# Priorities: the settle runs, then every low-res run before any high-res one. With one GPU job at a time
# (`--resources gpu=1`) the GPU then steps low-res shards while the cores make the scenes of later shards, and the
# high-res jobs, whose setup and writing keep the cores busy too, come last, all their inputs ready.

# The scenes whose sequences are simulated one job each (a pattern that matches nothing when there are none).
UNSHARDED = workflow_paths.one_of(s for s, settings in SETTINGS.items() if settings["shard"] == 1)


rule simulate_settle_low:
    input: settings=f"{OUT}/simulation.json", scene=f"{OUT}/settle/scene.h5"
    output: f"{OUT}/settle/sim_low.h5"
    wildcard_constraints: scene=LIBRARY_SCENES
    log: log_of("simulate_settle_low")
    benchmark: benchmark_of("simulate_settle_low")
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    priority: 20
    shell: "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} 2>&1 | tee {log:q}"


rule simulate_settle_high:
    input:
        settings=f"{OUT}/simulation.json", scene=f"{OUT}/settle/scene.h5", subdiv=f"{OUT}/subdiv.h5",
        sim_low=f"{OUT}/settle/sim_low.h5",
    output: f"{OUT}/settle/sim_high.h5"
    wildcard_constraints: scene=LIBRARY_SCENES
    log: log_of("simulate_settle_high")
    benchmark: benchmark_of("simulate_settle_high")
    threads: 1
    resources: mem_mb=8000, gpu=gpus_on_device
    priority: 20
    shell:
        "{PY:q} -m pipeline.simulate high {input.settings:q} {input.scene:q} {input.subdiv:q} {input.sim_low:q} "
        "{output:q} 2>&1 | tee {log:q}"


rule simulate_low:
    input: settings=f"{OUT}/simulation.json", scene=f"{SEQ}/scene.h5", settled=settled_runs("low")
    output: f"{SEQ}/sim_low.h5"
    wildcard_constraints: scene=UNSHARDED
    params: settled=settled_flag("low")
    log: log_of("simulate_low", per_sequence=True)
    benchmark: benchmark_of("simulate_low", per_sequence=True)
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    priority: 10
    shell:
        "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} {params.settled:q} 2>&1 "
        "| tee {log:q}"


rule simulate_high:
    input:
        settings=f"{OUT}/simulation.json", scene=f"{SEQ}/scene.h5", subdiv=f"{OUT}/subdiv.h5",
        sim_low=f"{SEQ}/sim_low.h5", settled=settled_runs("high"),
    output: f"{SEQ}/sim_high.h5"
    wildcard_constraints: scene=UNSHARDED
    params: settled=settled_flag("high")
    log: log_of("simulate_high", per_sequence=True)
    benchmark: benchmark_of("simulate_high", per_sequence=True)
    threads: 1
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.simulate high {input.settings:q} {input.scene:q} {input.subdiv:q} {input.sim_low:q} "
        "{output:q} {params.settled:q} 2>&1 | tee {log:q}"


# Sharded scenes: a rule per shard (a rule's outputs are fixed by its wildcards, and a shard's are a list of
# sequences), named simulate_low_batch_<scene>_<k> and simulate_high_batch_<scene>_<k>; logs and benchmarks per
# shard. Every path is a literal made here, so nothing from the config reaches the shell but quoted paths.
for _scene, _shards in ((s, sequence_shards(SETTINGS[s])) for s in SETTINGS if SETTINGS[s]["shard"] > 1):
    for _k, _names in enumerate(_shards):
        _out, _seqs = f"results/{_scene}", [f"results/{_scene}/sequences/{n}" for n in _names]
        _gpu = device_gpus(_scene)

        rule:
            name: workflow_paths.batch_rule_name("simulate_low", _scene, _k)
            input:
                settings=f"{_out}/simulation.json", scenes=[f"{s}/scene.h5" for s in _seqs],
                settled=workflow_paths.settled_runs(_scene, _names, "low"),
            output: [f"{s}/sim_low.h5" for s in _seqs]
            params:
                files=[p for s in _seqs for p in (f"{s}/scene.h5", f"{s}/sim_low.h5")],
                settled=workflow_paths.settled_flag(_scene, _names, "low"),
            log: f"{_out}/logs/shard_{_k:03d}/simulate_low.log"
            benchmark: f"{_out}/benchmarks/shard_{_k:03d}/simulate_low.tsv"
            threads: 1
            resources: mem_mb=4000 + 500 * len(_seqs), gpu=_gpu
            priority: 10
            shell:
                "{PY:q} -m pipeline.simulate low {input.settings:q} {params.files:q} {params.settled:q} 2>&1 "
                "| tee {log:q}"

        rule:
            name: workflow_paths.batch_rule_name("simulate_high", _scene, _k)
            input:
                settings=f"{_out}/simulation.json", subdiv=f"{_out}/subdiv.h5",
                scenes=[f"{s}/scene.h5" for s in _seqs], sim_low=[f"{s}/sim_low.h5" for s in _seqs],
                settled=workflow_paths.settled_runs(_scene, _names, "high"),
            output: [f"{s}/sim_high.h5" for s in _seqs]
            params:
                files=[p for s in _seqs
                       for p in (f"{s}/scene.h5", f"{_out}/subdiv.h5", f"{s}/sim_low.h5", f"{s}/sim_high.h5")],
                settled=workflow_paths.settled_flag(_scene, _names, "high"),
            log: f"{_out}/logs/shard_{_k:03d}/simulate_high.log"
            benchmark: f"{_out}/benchmarks/shard_{_k:03d}/simulate_high.tsv"
            threads: high_batch_threads(_scene, len(_seqs))
            resources: mem_mb=8000 + 2000 * len(_seqs), gpu=_gpu
            # The job spreads its products over its threads, a sequence each, one BLAS thread apiece: BLAS pools of
            # `threads` threads each (what Snakemake sets) crowd the cores the solver's construction needs meanwhile
            # (the paper pants' 64-sequence shard on the H100: solver 2.4 s and wall 51.7 s with them, 1.7 s and
            # 49.8 s without).
            shell:
                "OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 "
                "{PY:q} -m pipeline.simulate high {input.settings:q} {params.files:q} {params.settled:q} "
                "--threads {threads} 2>&1 | tee {log:q}"
