# A scene's resolved settings, its low-res scene (mesh, pins, mannequin) and the subdivided high-res mesh.
# Stages get only file paths: every value they use comes from settings.json, which is rewritten only when the
# scene's resolved settings change (the params trigger of `settings`), so a config change reruns exactly the
# scenes it touches.
from pipeline.config import write_settings


rule settings:
    output: f"{OUT}/settings.json"
    params: settings=lambda w: SETTINGS[w.scene]
    log: log_of("settings")
    benchmark: benchmark_of("settings")
    localrule: True
    threads: 1
    resources: mem_mb=500
    run:
        write_settings(params.settings, output[0])
        with open(log[0], "w") as f:
            print(f"{output[0]}: profile {params.settings['profile']}, device {params.settings['device']}", file=f)


rule scene:
    input: settings=f"{OUT}/settings.json"
    output: f"{OUT}/scene.h5"
    log: log_of("scene")
    benchmark: benchmark_of("scene")
    threads: 1
    resources: mem_mb=2000
    shell: "{PY:q} -m pipeline.scene {input.settings:q} {output:q} 2>&1 | tee {log:q}"


rule subdivide:
    input: settings=f"{OUT}/settings.json", scene=f"{OUT}/scene.h5"
    output: f"{OUT}/subdiv.h5"
    log: log_of("subdivide")
    benchmark: benchmark_of("subdivide")
    threads: 1
    resources: mem_mb=4000
    shell: "{PY:q} -m pipeline.subdivide {input.scene:q} {output:q} --settings {input.settings:q} 2>&1 | tee {log:q}"
