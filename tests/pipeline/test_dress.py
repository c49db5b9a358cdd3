"""The dress stage (pipeline/dress.py; issue 38): a garment file placed partly inside the mannequin ends the settle
clear of it with the file's edge lengths kept, its pins where they were placed; refined to max_edge when asked;
written as dressed.h5 and taken by the scene stage as the scene's rest mesh. And `scenes.<name>.like`, which lets
one overlay make a user's garment scene sized like a procedural one."""
from __future__ import annotations

import h5py
import numpy as np
import pytest
import yaml

from garment_files import write_garment_obj
from geometry.mesh import unique_edges
from pipeline import dress, scene
from pipeline.artifacts.dressed import read_dressed_garment
from pipeline.core.config import load_config, resolve_scene, shared_settings, simulation_settings, write_settings
from pipeline.core.errors import PipelineError
from scenes.capsules import capsule_signed_distance, capsules_world
from scenes.garments import make_garment
from scenes.kinematics import rest_transforms
from scenes.skeleton import default_skeleton

CONFIG = load_config("workflow_config.yaml")
SKELETON = default_skeleton()


def garment_settings(path, like="pants", profile="cpu", **fit) -> dict:
    config = {**CONFIG, "scenes": {**CONFIG["scenes"], "mine": {"like": like, "mesh": {
        "generator": "garment_file", "file": str(path), "units": "auto", "up": "auto", "weld": 1e-4, "max_edge": 0.16,
        "remesh": False, "pins": "auto",
        "fit": {"anchor": "auto", "offset": [0.0, 0.0, 0.0], "scale": 1.0, "settle_frames": 20, **fit}}}}}
    return shared_settings(resolve_scene(config, "mine", profile))


def clearance(points: np.ndarray) -> np.ndarray:
    """Each point's signed distance to the rest-pose mannequin's capsules."""
    a, b, ra, rb = capsules_world(SKELETON, rest_transforms(SKELETON))
    return capsule_signed_distance(points, a, b, ra, rb).min(axis=1)


def edge_ratio(x: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> np.ndarray:
    edges = unique_edges(faces)
    return (np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
            / np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1))


@pytest.mark.parametrize("kind, offset", [("pants", 0.03), ("tshirt", 0.05)])
def test_a_garment_placed_into_the_body_settles_clear_of_it_with_its_edge_lengths(tmp_path, kind, offset):
    path = tmp_path / f"{kind}.obj"
    write_garment_obj(path, kind, 0.16, units="cm" if kind == "pants" else "m")
    dressed = dress.dress(garment_settings(path, like=kind, offset=[offset, 0.0, 0.0]))
    garment = dressed.garment
    assert clearance(dressed.placed).min() < -0.0005          # placed 3-5 cm to the side: into the body
    assert clearance(garment.vertices).min() >= 0.0
    ratio = edge_ratio(garment.vertices, dressed.placed, garment.faces)
    assert dress.EDGE_TOLERANCE[0] <= ratio.min() and ratio.max() <= dress.EDGE_TOLERANCE[1]
    assert np.abs(ratio - 1).mean() < 0.01
    np.testing.assert_allclose(garment.vertices[garment.attachment], dressed.placed[garment.attachment], atol=1e-6)
    assert np.isclose(dressed.clearance[-1], clearance(garment.vertices).min())
    torso = {SKELETON.index(name) for name in ("pelvis", "spine", "chest")}
    assert set(garment.attachment_part.tolist()) <= torso


def test_a_refined_garment_has_every_edge_below_max_edge_and_is_dressed(tmp_path):
    path = tmp_path / "skirt.obj"
    write_garment_obj(path, "skirt", 0.25, units="mm")
    settings = garment_settings(path, like="skirt")
    settings["mesh"].update(remesh=True, max_edge=0.1)
    dressed = dress.dress(settings)
    vertices, faces = dressed.garment.vertices, dressed.garment.faces
    edges = unique_edges(faces)
    assert np.linalg.norm(dressed.placed[edges[:, 0]] - dressed.placed[edges[:, 1]], axis=1).max() < 0.1
    assert len(vertices) > 2 * len(make_garment("skirt", max_edge=0.25).vertices)
    assert clearance(vertices).min() >= 0.0


def test_dressed_h5_is_the_scene_stages_rest_mesh_and_says_how_it_was_made(tmp_path):
    path = tmp_path / "pants.obj"
    write_garment_obj(path, "pants", 0.25, units="cm", up="z", offset=(1.0, 2.0, 0.5))
    settings = garment_settings(path)
    write_settings(simulation_settings({**settings, "sequences": 1}), tmp_path / "simulation.json")
    dress.main([str(tmp_path / "simulation.json"), str(tmp_path / "dressed.h5")])
    with h5py.File(tmp_path / "dressed.h5") as f:
        attrs = dict(f.attrs)
    assert (attrs["units"], attrs["up"], attrs["anchor"], attrs["stage"]) == ("cm", "z", "waist", "dress")
    assert len(attrs["sha256"]) == 64 and attrs["clearance_m"] >= 0
    garment = read_dressed_garment(tmp_path / "dressed.h5", SKELETON.n_parts)
    scene.main([str(tmp_path / "simulation.json"), str(tmp_path / "scene.h5"), "--dressed",
                str(tmp_path / "dressed.h5")])
    with h5py.File(tmp_path / "scene.h5") as f:
        np.testing.assert_array_equal(f["rest/vertices"][()], garment.vertices)
        np.testing.assert_array_equal(f["pins/ids"][()], garment.attachment)
        np.testing.assert_array_equal(f["pins/part"][()], garment.attachment_part)
        assert "skinning/weights" in f
    with pytest.raises(PipelineError, match="--dressed is given exactly for a garment_file scene"):
        scene.main([str(tmp_path / "simulation.json"), str(tmp_path / "scene2.h5")])


def test_a_scene_like_another_takes_all_its_settings_and_profile_overlays_but_its_mesh(tmp_path):
    settings = garment_settings(tmp_path / "any.obj")
    pants = resolve_scene(CONFIG, "pants", "cpu")
    assert settings["mesh"]["generator"] == "garment_file" and "like" not in settings
    for key in ("frames", "drivers", "solver", "network", "training", "dataset", "physics", "evaluation"):
        assert settings[key] == pants[key], key
    paper = garment_settings(tmp_path / "any.obj", profile="paper")
    assert paper["frames"] == resolve_scene(CONFIG, "pants", "paper")["frames"] != settings["frames"]
    for like in ("nothing", "mine"):
        with pytest.raises(PipelineError, match=f"like: '{like}' is not another scene"):
            garment_settings(tmp_path / "any.obj", like=like)


def test_the_readmes_overlay_resolves_to_a_garment_file_scene_sized_like_pants():
    readme = open("README.md").read().split("## Your own garment", 1)[1]
    overlay = yaml.safe_load(readme.split("```yaml", 1)[1].split("```", 1)[0])
    config = {**CONFIG, "scenes": {**CONFIG["scenes"], **overlay["scenes"]}}
    (name,) = overlay["scenes"]
    settings = resolve_scene(config, name, "cpu")
    assert settings["mesh"]["generator"] == "garment_file" and settings["frames"] == resolve_scene(
        CONFIG, "pants", "cpu")["frames"]
