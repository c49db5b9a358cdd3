# A scene's resolved settings, what its sequences share (scene.h5: rest mesh, pins, skeleton, skinning), each
# sequence's scene (the motion and everything it moves) and the subdivided high-res mesh. Stages get only file
# paths and a sequence name: every value they use comes from settings.json (the learning stages) or
# simulation.json (the same less the network, its operators, training and evaluation: what the scene, subdivide
# and simulate stages read). Each is rewritten only when its content changes (the params trigger of its rule), so
# a config change reruns exactly the scenes and stages it touches: a new training setting retrains without
# simulating again, and raising the number of sequences reruns none of the sequences already made.
from pipeline.core.config import simulation_settings, write_settings


rule settings:
    output: f"{OUT}/settings.json"
    params: settings=lambda w: shared_settings(SETTINGS[w.scene])
    log: log_of("settings")
    benchmark: benchmark_of("settings")
    localrule: True     # a JSON file: in Snakemake's own process, never a cluster job
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: profile {params.settings['profile']}, device {params.settings['device']}", file=f)


rule simulation_settings:
    output: f"{OUT}/simulation.json"
    params: settings=lambda w: simulation_settings(SETTINGS[w.scene])
    log: log_of("simulation_settings")
    benchmark: benchmark_of("simulation_settings")
    localrule: True
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: profile {params.settings['profile']}, device {params.settings['device']}", file=f)


rule scene:
    input: settings=f"{OUT}/simulation.json"
    output: f"{OUT}/scene.h5"
    log: log_of("scene")
    benchmark: benchmark_of("scene")
    threads: 1
    resources: mem_mb=2000
    shell: "{PY:q} -m pipeline.scene {input.settings:q} {output:q} 2>&1 | tee {log:q}"


rule sequence:
    input: settings=f"{OUT}/simulation.json", bvh=bvh_files
    output: f"{SEQ}/scene.h5"
    log: log_of("sequence", per_sequence=True)
    benchmark: benchmark_of("sequence", per_sequence=True)
    threads: 1
    resources: mem_mb=2000
    priority: 10        # the low-res shards wait on them (simulate.smk: the order of the GPU's jobs)
    shell: "{PY:q} -m pipeline.scene {input.settings:q} {output:q} --sequence {wildcards.seq:q} 2>&1 | tee {log:q}"


# A scene with a motion library: the body at rest for settle_frames, whose cloth every window starts from once its
# runs settle it (simulate.smk).
rule settle_scene:
    input: settings=f"{OUT}/simulation.json"
    output: f"{OUT}/settle/scene.h5"
    wildcard_constraints: scene=LIBRARY_SCENES
    log: log_of("settle_scene")
    benchmark: benchmark_of("settle_scene")
    threads: 1
    resources: mem_mb=2000
    priority: 10
    shell: "{PY:q} -m pipeline.scene {input.settings:q} {output:q} --sequence settle 2>&1 | tee {log:q}"


rule subdivide:
    input: settings=f"{OUT}/simulation.json", scene=f"{OUT}/scene.h5"
    output: f"{OUT}/subdiv.h5"
    log: log_of("subdivide")
    benchmark: benchmark_of("subdivide")
    threads: 1
    resources: mem_mb=4000
    shell: "{PY:q} -m pipeline.subdivide {input.scene:q} {output:q} --settings {input.settings:q} 2>&1 | tee {log:q}"
