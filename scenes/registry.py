"""Scene assembly: resolved settings (pipeline.config) -> one typed `Scene`, made by the builder registered for
the settings' `mesh.generator`. A new scene kind (the hand) is one builder module and one entry here."""
from __future__ import annotations

from typing import Callable

from geometry.mesh import validate_mesh
from scenes.garment_scene import garment_scene
from scenes.grid_scene import grid_scene
from scenes.scene import Scene

SCENE_BUILDERS: dict[str, Callable[[dict], Scene]] = {"grid": grid_scene, "garment": garment_scene}


def build_scene(settings: dict) -> Scene:
    """The scene the settings describe, its rest mesh checked to be simulation-ready. Raises ValueError for
    settings no builder can realise (the scene stage names the scene in its error)."""
    generator = settings["mesh"]["generator"]
    if generator not in SCENE_BUILDERS:
        raise ValueError(f"unknown mesh generator '{generator}'; choose one of {', '.join(SCENE_BUILDERS)}")
    scene = SCENE_BUILDERS[generator](settings)
    validate_mesh(scene.rest_vertices, scene.rest_faces)
    return scene
