"""Dress stage: a garment from the user's file (`mesh.generator: garment_file`) dressed on the rest-pose mannequin,
settled clear of the body, with its pins: results/<scene>/dressed.h5, which the scene stage takes as the scene's
rest mesh (so every later stage treats it as it treats the procedural garments).

    python -m pipeline.dress SETTINGS.json OUT.h5

The file is read (pipeline.core.meshio: OBJ with its g/o groups, or any format trimesh reads), put in metres and
Y-up, its panels welded and optionally refined (scenes.garment_file); it is placed at its anchor, checked to go
around the body there, and its pins chosen (scenes.dressing); then a settle with the body takes it clear
(pipeline.solvers.dress_settle). A garment that cannot be dressed is one error saying what to set; the settled
garment must be clear of the body and keep the file's edge lengths within EDGE_TOLERANCE.
"""
from __future__ import annotations

import argparse
import hashlib
from pathlib import Path
from typing import Sequence

import numpy as np

from geometry.mesh import unique_edges
from pipeline.artifacts.dressed import Dressed, write_dressed
from pipeline.core import cli
from pipeline.core.config import LEARNING_ONLY, read_settings
from pipeline.core.errors import PipelineError
from pipeline.core.meshio import load_mesh_groups
from pipeline.solvers.dress_settle import settle_on_body
from pipeline.solvers.xpbd import solver_settings
from scenes.capsules import capsules_world
from scenes.dressing import TORSO_PARTS, check_encloses, guess_anchor, pin_vertices, place, push_outside
from scenes.garment_file import garment_from_file
from scenes.garments import Garment, RestMannequin
from scenes.skeleton import default_skeleton
from sim.solver import UnstableSimulation

# The settled garment's edges keep the file's lengths within these ratios: stretch is stiff (at most 10 %
# longer after the settle's few iterations), compression is the solver's allowance less 5 % (a fold).
EDGE_TOLERANCE = (0.70, 1.10)


def dress(settings: dict) -> Dressed:
    """The garment of `settings` dressed and settled; ValueError saying what to set where it cannot be."""
    mesh, fit = settings["mesh"], settings["mesh"]["fit"]
    path = Path(mesh["file"])
    vertices, faces, groups = load_mesh_groups(path)
    garment = garment_from_file(vertices, faces, mesh["units"], mesh["up"], mesh["weld"],
                                mesh["max_edge"] if mesh["remesh"] else None)
    body = RestMannequin(default_skeleton())
    anchor = guess_anchor(garment.vertices, garment.faces, body) if fit["anchor"] == "auto" else fit["anchor"]
    placed, top = place(garment.vertices, garment.faces, anchor, body, fit["scale"], np.asarray(fit["offset"]))
    check_encloses(placed, garment.faces, anchor, top, body)
    pinned = pin_vertices(mesh["pins"], top, groups, garment.file_to_mesh) if settings["physics"]["pins"] \
        else np.zeros(0, np.int64)
    solver = solver_settings(settings)
    placed[pinned] = push_outside(placed[pinned], body, 2 * solver.collision_thickness)
    a, b, ra, rb = capsules_world(body.skel, body.transforms)
    try:
        settled, stages = settle_on_body(placed, garment.faces, pinned, np.stack([a, b], 1), np.stack([ra, rb], 1),
                                         solver, fit["settle_frames"], settings["device"])
    except UnstableSimulation as err:
        raise ValueError(f"the settle blew up ({err.cause}): placed far inside the body? set mesh.fit.offset or "
                         f"mesh.fit.scale") from None
    clearance = np.array([body.distance(x).min() for x in stages])
    ratio = _edge_ratio(settled, placed, garment.faces)
    _check_settled(settled, clearance[-1], ratio, body, fit["scale"])
    attrs = dict(file=str(path), sha256=hashlib.sha256(path.read_bytes()).hexdigest(), units=garment.units,
                 up=garment.up, anchor=anchor, scale=fit["scale"], offset=list(fit["offset"]), weld=mesh["weld"],
                 file_vertices=len(vertices), vertices=len(settled), edge_ratio_min=ratio.min(),
                 edge_ratio_max=ratio.max(), edge_ratio_mean_abs=float(np.abs(ratio - 1).mean()),
                 clearance_m=clearance[-1])
    parts = body.nearest_part(placed[pinned], TORSO_PARTS if mesh["pins"] == "auto" else None)
    return Dressed(Garment("file", settled, garment.faces, pinned, parts), placed, stages, clearance, attrs)


def _check_settled(settled: np.ndarray, clearance: float, ratio: np.ndarray, body: RestMannequin,
                   scale: float) -> None:
    """The settled garment clear of the body and its edges within EDGE_TOLERANCE of the file's; ValueError saying
    what to set otherwise."""
    if clearance < 0:
        worst = int(np.argmin(body.distance(settled)))
        raise ValueError(f"it stays inside the body after the settle (vertex {worst} {-clearance * 100:.1f} cm deep at "
                         f"{np.round(settled[worst], 3).tolist()} m): set mesh.fit.scale above {scale:g} or "
                         f"mesh.fit.offset to give it room")
    if not (EDGE_TOLERANCE[0] <= ratio.min() and ratio.max() <= EDGE_TOLERANCE[1]):
        raise ValueError(f"the settle changed its edge lengths by {ratio.min():.2f}x to {ratio.max():.2f}x (allowed "
                         f"{EDGE_TOLERANCE[0]}-{EDGE_TOLERANCE[1]}x): too tight for the body where it is placed (set "
                         f"mesh.fit.scale above {scale:g} or mesh.fit.offset), or too fine a mesh for the solver's "
                         f"budget to hold it up (raise solver.iterations or solver.substeps, or give a coarser file)")


def _edge_ratio(x: np.ndarray, rest: np.ndarray, faces: np.ndarray) -> np.ndarray:
    edges = unique_edges(faces)
    length = lambda p: np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1)  # noqa: E731
    return length(x) / length(rest)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.dress", description=__doc__.splitlines()[0])
    parser.add_argument("settings", help="resolved scene settings (JSON) of a garment_file scene")
    parser.add_argument("out", help="dressed.h5 to write")
    args = parser.parse_args(argv)
    settings = read_settings(args.settings, unread=LEARNING_ONLY)
    if settings["mesh"]["generator"] != "garment_file":
        raise PipelineError(f"{args.settings}: scene '{settings['scene']}' is no garment_file scene (mesh.generator "
                            f"'{settings['mesh']['generator']}')")
    try:
        dressed = dress(settings)
    except ValueError as err:
        raise PipelineError(f"{settings['mesh']['file']}: {err}") from None
    write_dressed(args.out, dressed, settings)
    a = dressed.attrs
    print(f"{args.out}: {a['file']} in {a['units']}, {a['up']} up, worn at the {a['anchor']}: {a['vertices']} "
          f"vertices, {len(dressed.garment.attachment)} pinned; clear of the body by {a['clearance_m'] * 1000:.1f} "
          f"mm, edges {a['edge_ratio_min']:.3f}x-{a['edge_ratio_max']:.3f}x the file's")


if __name__ == "__main__":
    cli.run(main)
