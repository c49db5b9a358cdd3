"""Scene assembly: resolved settings (pipeline.core.config) -> the typed parts of a scene (scenes.scene), made by the
builders registered for the settings' `mesh.generator`: what every sequence shares (`build_rest`) and one
sequence (`build_scene`). A new cloth scene kind is one builder module and one entry here; the hand, whose data
are no cloth runs, is made by its own stage (pipeline/hand_scene.py). A garment from a file comes dressed
(pipeline/dress.py: its settle is a simulation, which no library here runs) and is passed in."""
from __future__ import annotations

from typing import Callable, NamedTuple

from geometry.mesh import validate_mesh
from scenes.garment_scene import garment_rest, garment_scene
from scenes.garments import Garment
from scenes.grid_scene import grid_rest, grid_scene
from scenes.scene import Scene, SceneRest


class SceneKind(NamedTuple):
    rest: Callable[..., SceneRest]                       # settings (, the dressed garment) -> what sequences share
    sequence: Callable[[dict, SceneRest, str], Scene]    # settings, rest, sequence name -> that sequence


SCENE_KINDS: dict[str, SceneKind] = {"grid": SceneKind(grid_rest, grid_scene),
                                     "garment": SceneKind(garment_rest, garment_scene),
                                     "garment_file": SceneKind(garment_rest, garment_scene)}


def build_rest(settings: dict, dressed: Garment | None = None) -> SceneRest:
    """What every sequence of the scene shares, its rest mesh checked to be simulation-ready; `dressed`: a
    garment_file scene's garment, dressed on the mannequin. Raises ValueError for settings no builder can realise
    (the scene stage names the scene in its error)."""
    kind = _kind(settings)
    rest = kind.rest(settings) if dressed is None else kind.rest(settings, dressed)
    validate_mesh(rest.vertices, rest.faces)
    return rest


def build_scene(settings: dict, sequence: str, dressed: Garment | None = None) -> Scene:
    """Sequence `sequence` (scenes.sequences) of the scene; ValueError as build_rest."""
    return _kind(settings).sequence(settings, build_rest(settings, dressed), sequence)


def _kind(settings: dict) -> SceneKind:
    generator = settings["mesh"]["generator"]
    if generator not in SCENE_KINDS:
        raise ValueError(f"unknown mesh generator '{generator}'; choose one of {', '.join(SCENE_KINDS)}")
    return SCENE_KINDS[generator]
