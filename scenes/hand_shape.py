"""The procedural hand's flesh: an implicit surface around its bones, the skin meshed from it, and the tet volume
the FEM solver deforms, with the nodes each bone drives and the skin embedded in the tets.

- Surface: a smooth union (polynomial smooth minimum) of tapered capsules: the skeleton's, plus three for the
  palm's outer metacarpals (the palm part's own capsule is the middle one), blended widely in the palm and
  narrowly at the finger joints, so that neighbouring fingers do not web together.
- Skin: marching tetrahedra of that function on a Kuhn grid of `skin_spacing`, relaxed to even triangles on the
  surface (geometry.isosurface): closed and manifold by construction.
- Volume: the Kuhn tets of a grid of `tet_spacing` that reach inside the surface, plus any that holds a skin
  vertex. This structured grid clipped to the surface was chosen over a conforming mesher: every tet is congruent
  (minimum dihedral angle 45 degrees, radius ratio 0.717; a conforming mesher's slivers are what limit a Newton
  solve's conditioning and inversion safety), the skin's resolution is independent of the volume's, and it needs
  no new package. The price is a shell of flesh up to one tet thick beyond the skin, which embedding hides.
  Tets are labelled with the chain (a finger, the thumb's phalanges, or the palm with forearm and thumb
  metacarpal) whose part is nearest; a node that tets of two different chains share is split into one copy per
  chain, so two fingers that the grid spans are not glued together (the palm's tets keep the original node).
- Bones: each part's bone is its capsule's axis shortened at the joints, with a radius of BONE_FRACTION of the
  flesh's (at least BONE_MIN_CELLS tet spacings); the nodes within a bone are driven rigidly by its part (the
  nearest bone where two reach), and a bone that holds fewer than MIN_GRIP nodes of a coarse grid grips its
  nearest ones.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from geometry.isosurface import marching_tetrahedra, relax_on_surface
from geometry.mesh import validate_mesh
from geometry.tets import dihedral_angles, kuhn_grid, radius_ratios
from scenes.capsules import capsule_signed_distance, capsules_world
from scenes.hand_skeleton import FINGERS, hand_skeleton
from scenes.kinematics import rest_transforms
from scenes.skeleton import Skeleton
from scenes.skinning import diffused_weights, linear_blend_skinning, rest_to_posed

# The palm's outer metacarpals in the palm frame: end a, end b, radius at a, radius at b.
PALM_CAPSULES = np.array([[0.024, 0.012, 0.0, 0.027, 0.080, 0.0], [-0.016, 0.012, 0.0, -0.018, 0.080, 0.0],
                          [-0.028, 0.015, 0.0, -0.034, 0.070, 0.0]])
PALM_RADII = np.array([[0.0135, 0.0120], [0.0130, 0.0115], [0.0120, 0.0105]])
PALM_BLEND = 0.014        # smooth-union width (m) within the palm group: fills the gaps between the metacarpals
JOINT_BLEND = 0.004       # at the finger and thumb joints and where a chain meets the palm
BONE_FRACTION = 0.45      # a bone's radius over its flesh's
BONE_MIN_CELLS = 0.6      # ... and at least this many tet spacings
JOINT_GAP = 0.6           # a bone stops this share of its flesh radius short of each joint
THUMB_BASE_GAP = 1.5      # the thumb's metacarpal bone starts well clear of its base joint: at rest it lies
                          # beside the index metacarpal, and the flesh between them is the thenar web
TIP_PAD = 0.9             # and this share short of a fingertip's capsule end (the pad is flesh)
MIN_GRIP = 6              # a bone drives at least this many nodes (not all in one plane)
SKIN_BLEND_WIDTH = 0.012
SPACING_RANGE = (0.0015, 0.012)   # metres: a fingertip is 13 mm across; a 1.5 mm grid of the hand's box is ~3M tets  # linear blend skinning weights diffuse over about this length (m)


def _smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - 0.25 * k * h * h


def chain_of_parts(skel: Skeleton) -> np.ndarray:
    """(P,) chain id of each part: 0 for the palm group (forearm, palm, thumb metacarpal), then one per finger
    and one for the thumb's phalanges."""
    chains = np.zeros(skel.n_parts, dtype=np.int64)
    for c, prefix in enumerate(("thumb", *FINGERS), start=1):
        for k in (1, 2, 3):
            if f"{prefix}_{k}" in skel.names:
                chains[skel.index(f"{prefix}_{k}")] = c
    return chains


@dataclass(frozen=True)
class RestShapes:
    """Every capsule of the rest hand, the skeleton's first then the palm's: ends (C, 3) x 2, radii (C,) x 2, and
    the part each belongs to (C,)."""
    a: np.ndarray
    b: np.ndarray
    ra: np.ndarray
    rb: np.ndarray
    part: np.ndarray

    @staticmethod
    def of(skel: Skeleton) -> "RestShapes":
        rotation, translation = rest_transforms(skel)
        a, b, ra, rb = capsules_world(skel, (rotation, translation))
        palm = skel.index("palm")
        # The palm's frame is the world's at rest up to its translation (no frame rotation on the way to it).
        offset = translation[palm]
        return RestShapes(np.concatenate([a, PALM_CAPSULES[:, :3] + offset]),
                          np.concatenate([b, PALM_CAPSULES[:, 3:] + offset]),
                          np.concatenate([ra, PALM_RADII[:, 0]]), np.concatenate([rb, PALM_RADII[:, 1]]),
                          np.concatenate([np.arange(skel.n_parts), np.full(len(PALM_CAPSULES), palm)]))

    def distances(self, points: np.ndarray) -> np.ndarray:
        """(N, C) signed distance of each point to each capsule."""
        return capsule_signed_distance(points, self.a, self.b, self.ra, self.rb)

    def nearest_part(self, points: np.ndarray) -> np.ndarray:
        """(N,) the part whose capsule is nearest each point."""
        return self.part[self.distances(points).argmin(axis=1)]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The lower and upper corners of the box holding every capsule."""
        r = np.maximum(self.ra, self.rb)[:, None]
        return np.minimum(self.a - r, self.b - r).min(axis=0), np.maximum(self.a + r, self.b + r).max(axis=0)


def hand_sdf(skel: Skeleton, shapes: RestShapes, points: np.ndarray) -> np.ndarray:
    """The flesh's implicit function at `points` (N, 3): negative inside, ~ the distance to the skin nearby."""
    d = shapes.distances(np.asarray(points, dtype=np.float64))
    chains = chain_of_parts(skel)[shapes.part]
    base = d[:, chains == 0]
    surface = base[:, 0]
    for k in range(1, base.shape[1]):
        surface = _smooth_min(surface, base[:, k], PALM_BLEND)
    for chain in range(1, chains.max() + 1):
        members = np.flatnonzero(chains == chain)
        part = d[:, members[0]]
        for k in members[1:]:
            part = _smooth_min(part, d[:, k], JOINT_BLEND)
        surface = _smooth_min(surface, part, JOINT_BLEND)
    return surface


def skin_mesh(skel: Skeleton, shapes: RestShapes, spacing: float,
              relax_iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """The rest skin: vertices (V, 3) and outward triangles (F, 3), checked manifold."""
    sdf = lambda p: hand_sdf(skel, shapes, p)  # noqa: E731
    origin, cells = grid_box(shapes.bounds(), spacing)
    nodes, tets = kuhn_grid(cells, origin, spacing)
    vertices, faces = marching_tetrahedra(nodes, tets, sdf(nodes))
    vertices = relax_on_surface(vertices, faces, sdf, relax_iterations, 1e-3 * spacing)
    validate_mesh(vertices, faces)
    return vertices, faces


def grid_box(bounds: tuple[np.ndarray, np.ndarray], spacing: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """A grid's origin and cells covering the box `bounds` (lower, upper corner) with two cells to spare."""
    lo, hi = bounds[0] - 2 * spacing, bounds[1] + 2 * spacing
    return lo, tuple(int(c) for c in np.ceil((hi - lo) / spacing))


@dataclass(frozen=True, eq=False)
class HandVolume:
    """The tet volume: nodes (N, 3), tets (T, 4), the driven nodes (D,) and the part driving each (D,), the skin's
    embedding (tet (S,), barycentric weights (S, 4)), and its element quality."""
    nodes: np.ndarray
    tets: np.ndarray
    driven: np.ndarray
    driven_part: np.ndarray
    embedding: tuple[np.ndarray, np.ndarray]
    node_influences: np.ndarray   # (N, 4) parts and weights of the nodes' own linear blend skinning: the warm
    node_weights: np.ndarray      # start of each frame's minimisation moves with it (FemInputs.node_motion)
    min_dihedral_deg: float
    min_radius_ratio: float
    split_nodes: int              # node copies made to keep chains apart


def hand_volume(skel: Skeleton, shapes: RestShapes, skin: np.ndarray, spacing: float,
                inside: Callable[[np.ndarray], np.ndarray], bounds: tuple[np.ndarray, np.ndarray]) -> HandVolume:
    """The tet volume of the flesh: the Kuhn tets of a grid of `spacing` over `bounds` that reach a node `inside`
    it (points (N, 3) -> (N,) bool) or hold a `skin` vertex, the chains split apart, the nodes within each of
    `shapes`' bones driven by its part."""
    origin, cells = grid_box(bounds, spacing)
    nodes, tets = kuhn_grid(cells, origin, spacing)
    keep = inside(nodes)[tets].any(axis=1)
    holder, weights = _grid_tet_of(skin, origin, spacing, cells, nodes, tets)
    keep[holder] = True
    kept = np.flatnonzero(keep)
    renumber = np.full(len(tets), -1)
    renumber[kept] = np.arange(len(kept))
    tets = tets[kept]
    chains = chain_of_parts(skel)[shapes.nearest_part(nodes[tets].mean(axis=1))]
    tets, copied = _split_chains(tets, chains)          # numbers only the nodes the kept tets use
    nodes = nodes[copied]
    driven, driven_part = _driven_nodes(skel, shapes, nodes, spacing)
    tet_faces = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]])
    node_influences, node_weights = diffused_weights(shapes.nearest_part(nodes), skel.n_parts, nodes, tet_faces,
                                                     SKIN_BLEND_WIDTH)
    return HandVolume(nodes, tets, driven, driven_part, (renumber[holder], weights), node_influences, node_weights,
                      float(dihedral_angles(nodes, tets).min()), float(radius_ratios(nodes, tets).min()),
                      int(len(copied) - len(np.unique(copied))))


def _grid_tet_of(points, origin, spacing, cells, nodes, tets) -> tuple[np.ndarray, np.ndarray]:
    """The grid tet holding each point (kuhn_grid numbers a cell's 6 tets consecutively) and its barycentric
    weights."""
    cell = np.clip(np.floor((points - origin) / spacing).astype(np.int64), 0, np.array(cells) - 1)
    first = 6 * ((cell[:, 0] * cells[1] + cell[:, 1]) * cells[2] + cell[:, 2])
    candidates = first[:, None] + np.arange(6)                                          # (S, 6)
    x = nodes[tets[candidates]]                                                         # (S, 6, 4, 3)
    Dm = np.transpose(x[:, :, 1:] - x[:, :, :1], (0, 1, 3, 2))
    lam = np.einsum("skij,skj->ski", np.linalg.inv(Dm), points[:, None] - x[:, :, 0])
    bary = np.concatenate([1 - lam.sum(axis=2, keepdims=True), lam], axis=2)            # (S, 6, 4)
    best = bary.min(axis=2).argmax(axis=1)
    rows = np.arange(len(points))
    return candidates[rows, best], bary[rows, best]


def _split_chains(tets: np.ndarray, chains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tets renumbered 0..K-1 over the nodes they use, so that no node is shared by two different chains other
    than the palm group (0), and for each new node the old node it copies."""
    corner_chain = np.repeat(chains, 4)
    node = tets.ravel()
    finger = corner_chain > 0
    pairs = np.unique(np.stack([node[finger], corner_chain[finger]], 1), axis=0)
    shared = np.bincount(pairs[:, 0], minlength=node.max() + 1) >= 2
    # A corner keeps its node unless the node is shared by several chains and the corner's tet is in a finger chain.
    copy = np.where(shared[node] & finger, corner_chain, 0)
    keys, new = np.unique(np.stack([node, copy], 1), axis=0, return_inverse=True)
    return new.reshape(-1, 4), keys[:, 0]


def _driven_nodes(skel: Skeleton, shapes: RestShapes, nodes: np.ndarray,
                  spacing: float) -> tuple[np.ndarray, np.ndarray]:
    axis = shapes.b - shapes.a
    length = np.linalg.norm(axis, axis=1)
    unit = axis / length[:, None]
    is_tip = np.zeros(len(length), dtype=bool)
    is_tip[[skel.index(f"{f}_3") for f in FINGERS] + [skel.index("thumb_2")]] = True
    gap = np.full(len(length), JOINT_GAP)
    gap[skel.index("thumb_0")] = THUMB_BASE_GAP
    start = shapes.a + (gap * shapes.ra)[:, None] * unit
    end = shapes.b - (np.where(is_tip, TIP_PAD, JOINT_GAP) * shapes.rb)[:, None] * unit
    bone_radius = np.maximum(BONE_FRACTION * np.minimum(shapes.ra, shapes.rb), BONE_MIN_CELLS * spacing)
    reach = capsule_signed_distance(nodes, start, end, bone_radius, bone_radius)       # (N, C)
    part_reach = np.full((len(nodes), skel.n_parts), np.inf)
    for c, p in enumerate(shapes.part):
        part_reach[:, p] = np.minimum(part_reach[:, p], reach[:, c])
    owner = np.where(part_reach.min(axis=1) < 0, part_reach.argmin(axis=1), -1)
    for p in range(skel.n_parts):
        # A bone that holds too few nodes of a coarse grid, or nodes all in one plane (which it could not hold
        # against bending), grips its nearest free nodes as well until it holds enough, out of plane.
        free = np.argsort(part_reach[:, p])
        free = free[owner[free] == -1][:MIN_GRIP * 4]
        extra = 0
        while _flat_or_few(nodes[owner == p], spacing) and extra < len(free):
            extra += 1
            owner[free[extra - 1]] = p
        if _flat_or_few(nodes[owner == p], spacing):
            raise ValueError(f"tet spacing {spacing} is too coarse to hold bone '{skel.names[p]}'")
    driven = np.flatnonzero(owner >= 0)
    return driven, owner[driven]


def _flat_or_few(points: np.ndarray, spacing: float) -> bool:
    return len(points) < MIN_GRIP or np.linalg.svd(points - points.mean(axis=0), compute_uv=False)[-1] < 0.1 * spacing


@dataclass(frozen=True, eq=False)
class Hand:
    """The procedural hand: its skeleton, rest skin (vertices, faces) with linear blend skinning weights
    (influences, weights (S, 4)), and its tet volume."""
    skeleton: Skeleton
    skin_vertices: np.ndarray
    skin_faces: np.ndarray
    skin_influences: np.ndarray
    skin_weights: np.ndarray
    volume: HandVolume

    def driven_targets(self, transforms: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """(..., D, 3) where the driven nodes go when the parts are at `transforms` ((..., P, 4), (..., P, 3)):
        each carried rigidly by its part from the rest pose."""
        affine = rest_to_posed(rest_transforms(self.skeleton), transforms)[..., self.volume.driven_part, :, :]
        rest = self.volume.nodes[self.volume.driven]
        return np.einsum("...dij,dj->...di", affine[..., :3], rest) + affine[..., 3]

    def node_motion(self, start: tuple[np.ndarray, np.ndarray], end: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """(..., N, 3) the nodes' linear blend skinning at `end` minus at `start` (part transforms as below)."""
        rest = rest_transforms(self.skeleton)
        vol = self.volume
        return (linear_blend_skinning(vol.nodes, vol.node_influences, vol.node_weights, rest, end)
                - linear_blend_skinning(vol.nodes, vol.node_influences, vol.node_weights, rest, start))

    def skinned(self, transforms: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """(..., S, 3) the skin by linear blend skinning: the predictor the network corrects."""
        return linear_blend_skinning(self.skin_vertices, self.skin_influences, self.skin_weights,
                                     rest_transforms(self.skeleton), transforms)


def flesh_hand(skel: Skeleton, shapes: RestShapes, vertices: np.ndarray, faces: np.ndarray, tet_spacing: float,
               inside: Callable[[np.ndarray], np.ndarray], bounds: tuple[np.ndarray, np.ndarray]) -> Hand:
    """The hand of a skeleton, its flesh's capsules (`shapes`) and rest skin: the skin's linear blend skinning and
    the tet volume (`hand_volume`)."""
    influences, weights = diffused_weights(shapes.nearest_part(vertices), skel.n_parts, vertices, faces,
                                           SKIN_BLEND_WIDTH)
    volume = hand_volume(skel, shapes, vertices, tet_spacing, inside, bounds)
    return Hand(skel, vertices, faces, influences, weights, volume)


def procedural_hand(skin_spacing: float, tet_spacing: float, relax_iterations: int = 10) -> Hand:
    """The hand with its skin meshed at `skin_spacing` and its volume at `tet_spacing` (metres): about 3.5k skin
    vertices and 8k tets at 0.008, 26k and 30k at 0.003 and 0.005. Spacings outside SPACING_RANGE are refused
    (ValueError): coarser, a grid cell outgrows a fingertip; finer, the grids no longer fit in memory."""
    for name, spacing in (("skin spacing", skin_spacing), ("tet spacing", tet_spacing)):
        check_spacing(name, spacing)
    skel = hand_skeleton()
    shapes = RestShapes.of(skel)
    vertices, faces = skin_mesh(skel, shapes, skin_spacing, relax_iterations)
    return flesh_hand(skel, shapes, vertices, faces, tet_spacing, lambda p: hand_sdf(skel, shapes, p) < 0,
                      shapes.bounds())


def check_spacing(name: str, spacing: float) -> None:
    """ValueError for a spacing outside SPACING_RANGE (or NaN)."""
    if not SPACING_RANGE[0] <= spacing <= SPACING_RANGE[1]:
        raise ValueError(f"{name} {spacing} m is outside [{SPACING_RANGE[0]}, {SPACING_RANGE[1]}] m")
