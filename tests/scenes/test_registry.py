"""Scene assembly: the registry turns resolved settings into what a scene's sequences share and one typed
Scene per sequence, with the parts of its kind."""
import numpy as np
import pytest
import yaml

from geometry.rigid import apply_rigid
from pipeline.core.config import resolve_scene
from scenes.registry import SCENE_KINDS, build_rest, build_scene
from scenes.sequences import HAND_GENERATORS

CONFIG = yaml.safe_load(open("workflow_config.yaml"))
SCHEMA = yaml.safe_load(open("workflow/config.schema.yaml"))


def test_every_cloth_generator_of_the_schema_has_a_builder():
    """The hand's generators have none: their scenes are made by their own stage (pipeline/hand_scene.py)."""
    generators = []

    def collect(node):
        if isinstance(node, dict):
            if "generator" in node.get("properties", {}):
                generators.extend(node["properties"]["generator"]["enum"])
            for value in node.values():
                collect(value)
    collect(SCHEMA)
    assert generators and set(generators) - set(HAND_GENERATORS) == set(SCENE_KINDS)


def test_a_grid_scene_has_a_rod_and_no_mannequin():
    settings = resolve_scene(CONFIG, "flag", "cpu")
    scene = build_scene(settings, "train_000")
    assert scene.rest.name == "flag" and scene.rest.generator == "grid" and scene.n_frames == settings["frames"]
    assert scene.mannequin is None and scene.rod is not None and scene.rest.skeleton is None
    pins = scene.pins
    assert len(pins.ids) > 2 and set(pins.part) == {0} and pins.transforms.shape == (scene.n_frames, 1, 4, 4)
    # the rod's own formula, independently of the 4 x 4 transforms
    rest = scene.rest.vertices[pins.ids]
    rod = np.einsum("fij,pj->fpi", scene.rod.rotation, rest - scene.rod.pivot) + scene.rod.pivot \
        + scene.rod.translation[:, None]
    np.testing.assert_allclose(pins.targets, rod, atol=1e-12)
    np.testing.assert_allclose(pins.targets, apply_rigid(pins.transforms[:, pins.part], rest), atol=0)


def test_a_garment_scene_has_a_mannequin_and_no_rod():
    settings = resolve_scene(CONFIG, "skirt", "cpu")
    scene = build_scene(settings, "held_out_000")
    assert scene.rest.generator == "garment" and scene.rod is None
    mannequin = scene.mannequin
    n, parts = scene.n_frames, scene.rest.skeleton.n_parts
    assert mannequin.clips.names == ("settle", "walk") and len(mannequin.clips.clip) == n
    assert mannequin.capsules.a.shape == (n, parts, 3) and mannequin.capsules.radius_a.shape == (parts,)
    assert mannequin.state.rotation.shape == (n, parts, 4) and mannequin.torso_transforms.shape == (n, 4, 4)
    assert scene.rest.skinning_weights.shape == (len(scene.rest.vertices), 4)
    with pytest.raises(ValueError, match="a grid scene has one sequence, train_000; got 'train_001'"):
        build_scene(resolve_scene(CONFIG, "flag", "cpu"), "train_001")


def test_unknown_generators_and_unbuildable_settings_are_value_errors():
    settings = resolve_scene(CONFIG, "patch", "cpu")
    with pytest.raises(ValueError, match="unknown mesh generator 'hand'; choose one of grid, garment"):
        build_rest({**settings, "mesh": {**settings["mesh"], "generator": "hand"}})
    with pytest.raises(ValueError, match="unknown pin rule"):
        build_scene({**settings, "drivers": {**settings["drivers"], "pins": "middle"}}, "train_000")
