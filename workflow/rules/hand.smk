# The hand scenes (mesh.generator hand or hand_file; paper Table 4, "hand"): the procedural hand's skin or the
# user's own (its skin and bone files are the rule's inputs, so editing them makes the hand again) and its tet
# volume (hand.h5), each shard of sequences simulated by the quasi-static FEM as one batch of worlds (a fem.h5 per
# sequence), and their dataset (18 joint angles in, linear blend skinning as predictor, FEM - LBS as target). The
# operators (on the skin), training and evaluation are learning.smk's, as for any scene; `results/<hand scene>/`
# stands for all of it (common.smk: scene_products). Every path in a shell is a quoted literal or wildcard.

HAND_SCENES = workflow_paths.one_of(s for s, settings in SETTINGS.items() if workflow_paths.is_hand(settings))

# A hand scene's dataset.h5 is made from its FEM runs, not from cloth runs.
ruleorder: hand_dataset > dataset


rule hand_scene:
    input: settings=f"{OUT}/simulation.json", files=lambda w: workflow_paths.hand_files(SETTINGS[w.scene])
    output: f"{OUT}/{workflow_paths.HAND_MESH}"
    wildcard_constraints: scene=HAND_SCENES
    log: log_of("hand_scene")
    benchmark: benchmark_of("hand_scene")
    threads: 1
    resources: mem_mb=4000
    shell: "{PY:q} -m pipeline.hand_scene {input.settings:q} {output:q} 2>&1 | tee {log:q}"


rule hand_dataset:
    input:
        settings=f"{OUT}/simulation.json", hand=f"{OUT}/{workflow_paths.HAND_MESH}",
        runs=sequence_files(workflow_paths.HAND_RUN),
    output: f"{OUT}/dataset.h5"
    wildcard_constraints: scene=HAND_SCENES
    params: sequences=sequence_folders
    log: log_of("dataset")
    benchmark: benchmark_of("dataset")
    threads: 1
    resources: mem_mb=8000
    shell:
        "{PY:q} -m pipeline.hand_dataset {input.hand:q} {output:q} {params.sequences:q} "
        "--settings {input.settings:q} --quiet 2>&1 | tee {log:q}"


# A rule per shard of a hand scene (scenes.sequences.sequence_shards: training and held-out sequences apart),
# named hand_simulate_batch_<scene>_<k>; its sequences are one batch of FEM worlds.
for _scene in (s for s in SETTINGS if workflow_paths.is_hand(SETTINGS[s])):
    for _k, _names in enumerate(sequence_shards(SETTINGS[_scene])):
        _out = f"results/{_scene}"
        _runs = [f"{_out}/sequences/{n}/{workflow_paths.HAND_RUN}" for n in _names]

        rule:
            name: workflow_paths.batch_rule_name("hand_simulate", _scene, _k)
            input: settings=f"{_out}/simulation.json", hand=f"{_out}/{workflow_paths.HAND_MESH}"
            output: _runs
            params: runs=[p for name, run in zip(_names, _runs) for p in (name, run)]
            log: f"{_out}/logs/shard_{_k:03d}/hand_simulate.log"
            benchmark: f"{_out}/benchmarks/shard_{_k:03d}/hand_simulate.tsv"
            threads: 1
            resources: mem_mb=4000 + 1000 * len(_names), gpu=device_gpus(_scene)
            priority: 10
            shell:
                "{PY:q} -m pipeline.hand_simulate {input.settings:q} {input.hand:q} {params.runs:q} --quiet 2>&1 "
                "| tee {log:q}"
