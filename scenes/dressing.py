"""Dressing a garment from a file (scenes.garment_file) on the rest-pose mannequin: how it is worn (its anchor,
guessed from its openings or given), where it goes, whether it goes around the body where it should, and which
of its vertices are pinned to which body part. The settle that then takes it clear of the body is a simulation
(pipeline/dress.py); this module is geometry only.

Anchors, and where each puts the garment's top opening (the heights of the procedural garments, scenes.garments):
- waist: the top opening's centre at the waist (5 cm above the pelvis joint): trousers, skirts;
- shoulders: the garment's highest point 4 cm above the shoulder joints' capsules, its top opening (the collar)
  centred on the neck: shirts, dresses with straps;
- chest: the top opening's centre at the armpits (15 cm below the shoulder joints): tube tops.
Lengths scale with the mannequin's height (1.7 m).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.mesh import boundary_loops
from scenes.garment_file import CLOSED_SURFACE
from scenes.garments import RestMannequin

ANCHORS = ("waist", "shoulders", "chest")
# The parts an automatic pin (a waistband, a collar) may follow: the torso carries them. A collar nearer the
# upper arm than the chest would otherwise be dragged by the arm and tear at the shoulder.
TORSO_PARTS = ("pelvis", "spine", "chest")
# The ease a loose opening has around the body when a tube is worn at the waist or at the chest: 3 cm all round.
TUBE_EASE = 0.03


@dataclass(frozen=True, eq=False)
class Opening:
    """A boundary loop of the garment: an opening (waist, neck, hem, leg, sleeve)."""
    loop: np.ndarray        # (k,) vertex ids in walking order
    centre: np.ndarray      # (3,) mean of its vertices
    perimeter: float


def openings(vertices: np.ndarray, faces: np.ndarray) -> list[Opening]:
    """The garment's openings, highest centre first."""
    found = []
    for loop in boundary_loops(len(vertices), faces):
        points = vertices[loop]
        found.append(Opening(loop, points.mean(axis=0),
                             float(np.linalg.norm(points - np.roll(points, -1, axis=0), axis=1).sum())))
    return sorted(found, key=lambda o: -o.centre[1])


def guess_anchor(vertices: np.ndarray, faces: np.ndarray, body: RestMannequin) -> str:
    """How a garment is worn, from its openings: two side by side at its bottom are legs (waist); two at its sides
    above its lowest are sleeves or armholes (shoulders); a tube's top opening sized for the waist or the chest
    (whichever girth, with TUBE_EASE, it is nearer). ValueError where the openings cannot tell."""
    found = openings(vertices, faces)
    if not found:
        raise ValueError(CLOSED_SURFACE)
    if len(found) == 1:
        raise ValueError("one opening only (a cape, a bib?): cannot tell how it is worn; set mesh.fit.anchor to "
                         f"one of {', '.join(ANCHORS)}")
    top = found[0]
    if len(found) == 2:
        ease = 2 * np.pi * TUBE_EASE * body.scale
        waist, chest = body.girth("pelvis") + ease, body.girth("chest") + ease
        return "waist" if abs(top.perimeter - waist) <= abs(top.perimeter - chest) else "chest"
    height = float(np.ptp(vertices[:, 1]))
    a, b = found[-2], found[-1]
    side_by_side = (a.centre[0] - top.centre[0]) * (b.centre[0] - top.centre[0]) < 0
    if side_by_side and abs(a.centre[1] - b.centre[1]) < 0.15 * height and top.centre[1] - a.centre[1] > 0.5 * height:
        return "waist"
    return "shoulders"


def place(vertices: np.ndarray, faces: np.ndarray, anchor: str, body: RestMannequin, scale: float,
          offset: np.ndarray) -> tuple[np.ndarray, Opening]:
    """The garment scaled by `scale`, moved to its anchor on the rest-pose body (module docstring), then by
    `offset` (metres); also its top opening (the waistband, collar or top hem), whose vertices the automatic pins
    are."""
    vertices = np.asarray(vertices, dtype=np.float64) * scale
    top = openings(vertices, faces)[0]
    s = body.scale
    arm = body.skel.index("upper_arm_l")
    if anchor == "waist":
        shift = body.joint("pelvis") + [0.0, 0.05 * s, 0.0] - top.centre
    elif anchor == "chest":
        shift = body.joint("chest") * [1, 0, 1] + [0.0, body.joint("upper_arm_l")[1] - 0.15 * s, 0.0] - top.centre
    else:
        shift = body.joint("head") - top.centre
        shift[1] = body.joint("upper_arm_l")[1] + body.ra[arm] + 0.04 * s - vertices[:, 1].max()
    shift = shift + np.asarray(offset, dtype=np.float64)
    return vertices + shift, Opening(top.loop, top.centre + shift, top.perimeter)


def winding(loop_points: np.ndarray, centre: np.ndarray) -> int:
    """How many times a closed loop turns about the vertical line through `centre` (seen from above)."""
    rel = loop_points[:, [0, 2]] - centre[[0, 2]]
    angle = np.arctan2(rel[:, 1], rel[:, 0])
    turn = np.diff(np.append(angle, angle[0]))
    return int(round(float(((turn + np.pi) % (2 * np.pi) - np.pi).sum()) / (2 * np.pi)))


def check_encloses(vertices: np.ndarray, faces: np.ndarray, anchor: str, top: Opening, body: RestMannequin) -> None:
    """The placed garment goes around the body where it is worn: its top opening around the torso (waist, chest)
    or the neck (shoulders) and, for trousers, each leg opening around its own leg. ValueError saying what to
    set otherwise (a garment cut open down one side, a misplaced or mis-scaled one)."""
    around = {"waist": "pelvis", "chest": "chest", "shoulders": "head"}[anchor]
    if abs(winding(vertices[top.loop], body.joint(around))) != 1:
        raise ValueError(f"its top opening (centre {np.round(top.centre, 3).tolist()} m) does not go around the "
                         f"body's {around} once: it is not worn at the {anchor} (set mesh.fit.anchor), is placed off "
                         f"the body (mesh.fit.offset, mesh.fit.scale), or is cut open (sew seams with mesh.weld)")
    if anchor != "waist":
        return
    legs = [o for o in openings(vertices, faces)[1:] if o.centre[1] < body.joint("thigh_l")[1] - 0.2 * body.scale]
    if len(legs) >= 2:
        for leg in legs[-2:]:
            side = "thigh_l" if leg.centre[0] > body.joint("pelvis")[0] else "thigh_r"
            if abs(winding(vertices[leg.loop], body.joint(side))) != 1:
                raise ValueError(f"its leg opening at {np.round(leg.centre, 3).tolist()} m does not go around the "
                                 f"{'left' if side.endswith('_l') else 'right'} leg: set mesh.fit.offset or "
                                 f"mesh.fit.scale")


def push_outside(points: np.ndarray, body: RestMannequin, clearance: float, steps: int = 50) -> np.ndarray:
    """Points moved out of the body until each is at least `clearance` from it, along the distance's gradient
    (finite differences), for the pins, which the settle cannot move."""
    points = np.array(points, dtype=np.float64)
    h = 1e-4 * body.scale
    for _ in range(steps):
        gap = body.distance(points) - clearance
        inside = gap < 0
        if not inside.any():
            break
        p = points[inside]
        grad = np.stack([(body.distance(p + h * e) - body.distance(p - h * e)) / (2 * h) for e in np.eye(3)], 1)
        grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
        points[inside] = p - gap[inside, None] * grad * 1.01
    return points


def pin_vertices(spec, top: Opening, groups: dict[str, np.ndarray], file_to_mesh: np.ndarray) -> np.ndarray:
    """The pinned vertex ids of the mesh: `auto` the top opening (waistband, collar: each follows the nearest of
    TORSO_PARTS), `{group: NAME}` the
    vertices of the file's group NAME, `{indices: [...]}` the file's vertices by their 0-based number. ValueError
    naming a group the file has not or an index beyond its vertices."""
    if spec == "auto":
        return np.unique(top.loop)
    if "group" in spec:
        if spec["group"] not in groups:
            known = ", ".join(sorted(groups)) or "none"
            raise ValueError(f"mesh.pins.group '{spec['group']}' is no group of the file (its g/o groups: {known})")
        file_ids = groups[spec["group"]]
    else:
        file_ids = np.asarray(spec["indices"], dtype=np.int64)
        if len(file_ids) and file_ids.max() >= len(file_to_mesh):
            raise ValueError(f"mesh.pins.indices: {int(file_ids.max())} is beyond the file's {len(file_to_mesh)} "
                             f"vertices (numbered from 0)")
    return np.unique(file_to_mesh[file_ids])
