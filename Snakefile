# Wiring only: every stage is a `python -m pipeline.<stage>` CLI that reads and writes HDF5 artifacts under
# results/{scene}/. `snakemake --cores 2 results/<scene>/` builds everything a scene has; any artifact path is
# a target too (e.g. results/patch/sim_high.h5), and `--forcerun <rule>` reruns one stage.
import sys

sys.path.insert(0, workflow.basedir)

from snakemake.utils import validate

from pipeline.config import resolve_scene, validate_config, write_settings

configfile: "workflow_config.yaml"

# Our validator first: it names the offending key in one line; Snakemake's then records the schema check.
validate_config(config, "workflow config")
validate(config, "workflow/config.schema.yaml")

# Resolving every scene now turns a bad or missing key into one error before any job starts.
SETTINGS = {scene: resolve_scene(config, scene) for scene in config["scenes"]}
PY = sys.executable
OUT = "results/{scene}"

wildcard_constraints:
    scene="|".join(SETTINGS),


rule settings:
    output: f"{OUT}/settings.json"
    params: settings=lambda w: SETTINGS[w.scene]  # a changed setting reruns the scene
    run:
        write_settings(params.settings, output[0])


rule scene:
    input: f"{OUT}/settings.json"
    output: f"{OUT}/scene.h5"
    shell: "{PY} -m pipeline.scene {input} {output}"


rule subdivide:
    input: f"{OUT}/scene.h5"
    output: f"{OUT}/subdiv.h5"
    params:
        levels=lambda w: SETTINGS[w.scene]["high_res"]["subdivision_levels"],
        per_harmonic=lambda w: SETTINGS[w.scene]["high_res"]["vertices_per_harmonic"],
    shell: "{PY} -m pipeline.subdivide {input} {output} --levels {params.levels} --vertices-per-harmonic {params.per_harmonic}"


rule simulate_low:
    input: settings=f"{OUT}/settings.json", scene=f"{OUT}/scene.h5"
    output: f"{OUT}/sim_low.h5"
    shell: "{PY} -m pipeline.simulate low {input.settings} {input.scene} {output}"


rule simulate_high:
    input:
        settings=f"{OUT}/settings.json", scene=f"{OUT}/scene.h5", subdiv=f"{OUT}/subdiv.h5",
        sim_low=f"{OUT}/sim_low.h5",
    output: f"{OUT}/sim_high.h5"
    shell: "{PY} -m pipeline.simulate high {input.settings} {input.scene} {input.subdiv} {input.sim_low} {output}"


def scene_products(scene):
    """Everything `results/<scene>/` stands for."""
    return [f"results/{scene}/{name}" for name in ("sim_low.h5", "sim_high.h5")]


# `results/<scene>/` as a target: a rule named after the folder (a directory output would clash with the
# artifacts inside it), with and without the trailing slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/", f"results/{_scene}"):
        rule:
            name: _target
            input: scene_products(_scene)
