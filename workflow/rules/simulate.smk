# The XPBD runs of each sequence on the scene's device: low-res, then high-res held to it by the harmonic
# constraint. Sequences are independent jobs: Snakemake runs as many side by side as cores (or GPUs) allow.


rule simulate_low:
    input: settings=f"{OUT}/settings.json", scene=f"{SEQ}/scene.h5"
    output: f"{SEQ}/sim_low.h5"
    log: log_of("simulate_low", per_sequence=True)
    benchmark: benchmark_of("simulate_low", per_sequence=True)
    threads: 1
    resources: mem_mb=4000, gpu=gpus_on_device
    shell: "{PY:q} -m pipeline.simulate low {input.settings:q} {input.scene:q} {output:q} 2>&1 | tee {log:q}"


rule simulate_high:
    input:
        settings=f"{OUT}/settings.json", scene=f"{SEQ}/scene.h5", subdiv=f"{OUT}/subdiv.h5",
        sim_low=f"{SEQ}/sim_low.h5",
    output: f"{SEQ}/sim_high.h5"
    log: log_of("simulate_high", per_sequence=True)
    benchmark: benchmark_of("simulate_high", per_sequence=True)
    threads: 1
    resources: mem_mb=8000, gpu=gpus_on_device
    shell:
        "{PY:q} -m pipeline.simulate high {input.settings:q} {input.scene:q} {input.subdiv:q} {input.sim_low:q} "
        "{output:q} 2>&1 | tee {log:q}"
