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


def setting(*keys):
    """A params function reading settings[keys...] of the job's scene; a list comes as one comma-joined word."""
    def get(wildcards):
        value = SETTINGS[wildcards.scene]
        for key in keys:
            value = value[key]
        return ",".join(map(str, value)) if isinstance(value, list) else value
    return get


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
        levels=setting("high_res", "subdivision_levels"),
        per_harmonic=setting("high_res", "vertices_per_harmonic"),
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


rule operators:
    input: f"{OUT}/subdiv.h5"
    output: f"{OUT}/operators.h5"
    params:
        conv=setting("operators", "conv"),
        levels=setting("operators", "levels"),
    shell: "{PY} -m pipeline.operators {input} {output} --conv {params.conv} --levels {params.levels} --quiet"


rule dataset:
    input:
        sim_low=f"{OUT}/sim_low.h5", sim_high=f"{OUT}/sim_high.h5", subdiv=f"{OUT}/subdiv.h5",
        scene=f"{OUT}/scene.h5",
    output: f"{OUT}/dataset.h5"
    params:
        frame=setting("dataset", "frame"),
        split=lambda w: ("--test-clips " + setting("drivers", "mannequin", "test_clips")(w)
                         if SETTINGS[w.scene]["dataset"]["split"] == "held_out" else ""),
        fraction=setting("dataset", "test_fraction"),
        seed=setting("dataset", "seed"),
    shell:
        "{PY} -m pipeline.dataset {input.sim_low} {input.sim_high} {input.subdiv} {output} --scene {input.scene} "
        "--frame {params.frame} {params.split} --test-fraction {params.fraction} --seed {params.seed} --quiet"


rule train:
    input: dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5"
    output: model=f"{OUT}/model.pt", log=f"{OUT}/train.h5"
    threads: workflow.cores
    params:
        network=setting("network"), training=setting("training"), device=setting("device"),
    shell:
        "{PY} -m pipeline.train {input.dataset} {input.operators} {output.model} {output.log} "
        "--arch '{params.network[arch]}' --conv {params.network[conv]} --pool {params.network[pool]} "
        "--width {params.network[width]} --epochs {params.training[epochs]} "
        "--batch-size {params.training[batch_size]} --lr {params.training[lr]} --seed {params.training[seed]} "
        "--loss-l1 {params.training[loss][l1]} --loss-l2 {params.training[loss][l2]} "
        "--loss-normal {params.training[loss][normal]} --device {params.device} --threads {threads} --quiet"


rule evaluate:
    input:
        dataset=f"{OUT}/dataset.h5", operators=f"{OUT}/operators.h5", model=f"{OUT}/model.pt",
        scene=f"{OUT}/scene.h5",
    output:
        eval=f"{OUT}/eval.h5", report=f"{OUT}/report.md",
        renders=directory(f"{OUT}/renders"), export=directory(f"{OUT}/export"),
    threads: workflow.cores
    params: evaluation=setting("evaluation"), device=setting("device"),
    shell:
        "{PY} -m pipeline.evaluate {input.dataset} {input.operators} {input.model} {output.eval} {output.report} "
        "--scene {input.scene} --renders {output.renders} --export {output.export} "
        "--render-frames {params.evaluation[render_frames]} --export-frames {params.evaluation[export_frames]} "
        "--timing-frames {params.evaluation[timing_frames]} --device {params.device} --threads {threads} --quiet"


PRODUCTS = ("sim_low.h5", "sim_high.h5", "operators.h5", "dataset.h5", "model.pt", "train.h5", "eval.h5",
            "report.md", "renders", "export")


def scene_products(scene):
    """Everything `results/<scene>/` stands for."""
    return [f"results/{scene}/{name}" for name in PRODUCTS]


# `results/<scene>/` as a target: a rule named after the folder (a directory output would clash with the
# artifacts inside it), with and without the trailing slash.
for _scene in SETTINGS:
    for _target in (f"results/{_scene}/", f"results/{_scene}"):
        rule:
            name: _target
            input: scene_products(_scene)
