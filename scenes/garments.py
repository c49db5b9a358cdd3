"""Procedural garments fitted around the rest-pose mannequin: patch, cape, skirt, pants, tshirt and dress.

Every garment is assembled from parametric pieces sampled on a grid of spacing SPACING * max_edge (so that quad
diagonals stay below max_edge): tubes of rings around body parts, and panels. Ring sizes are fitted to the body:
a convex template ring is scaled until every point of it is `ease` away from the relevant capsules. Pieces share
their border vertices, so the result is one manifold mesh:

- skirt: one tube from the waist, flaring below the hips (2 boundary loops: waist, hem);
- pants: a waist tube whose lowest ring splits, through a crotch seam running front to back under the pelvis,
  into two leg loops, each continued by a leg tube (genus 0, 3 boundary loops: waist and two leg openings);
- tshirt: a torso tube up to the armpits, then a front and a back panel that meet along the shoulder seams,
  leaving the neck hole and two armholes, and a sleeve tube on each armhole (4 loops: neck, hem, 2 sleeves);
- dress: the tshirt's upper body without sleeves, its torso tube flaring to below the knees (4 loops: neck, two
  armholes, hem);
- cape: a panel hanging down the back from an arc around the neck (1 loop); patch: a flat bib in front of the
  chest (1 loop).

Faces are oriented so that normals point away from the body. Each piece's quads are split along the shorter
diagonal; a piece's grid runs with its columns and rows such that (column direction) x (row direction) points
outward. Attachment vertices (waist band, shoulder seams, top edges) are returned with the part they follow.

With `panels`, the garment is then cut along seams into separate pieces whose seam vertices are duplicated, as
an artist's export of a garment sewn from panels is (see `_panel_seams`); `Garment.welded` sews them back.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from geometry.mesh import cut_along_edges, edge_faces, validate_mesh, weld_vertices
from scenes.capsules import body_signed_distance, capsule_signed_distance, capsules_world
from scenes.kinematics import rest_transforms
from scenes.skeleton import Skeleton, default_skeleton

GARMENT_KINDS = ("patch", "cape", "skirt", "pants", "tshirt", "dress")
BOUNDARY_LOOPS = {"patch": 1, "cape": 1, "skirt": 2, "pants": 3, "tshirt": 4, "dress": 4}
SPACING = 0.6      # grid spacing as a fraction of max_edge: a square's diagonal is 0.85 max_edge
CLEARANCE = 0.01   # least gap between any garment vertex and the rest-pose body, for a 1.7 tall body
# Panel layout: horizontal seams at these fractions of the garment's height below its top.
PANEL_SEAM_DEPTHS = (0.1, 0.4, 0.7)


@dataclass(frozen=True, eq=False)
class Garment:
    """A garment mesh at rest around the rest-pose body, and the vertices that follow the body."""
    kind: str
    vertices: np.ndarray         # (V, 3) float64
    faces: np.ndarray            # (F, 3) int64, normals pointing away from the body
    attachment: np.ndarray       # (A,) int64 vertex indices
    attachment_part: np.ndarray  # (A,) int64 skeleton part each attachment vertex follows

    def welded(self, tolerance: float) -> "Garment":
        """The garment with vertices closer than `tolerance` merged (geometry.mesh.weld_vertices): separate panels
        sewn back into one mesh. Attachment vertices that merge keep their first entry."""
        vertices, faces, old_to_new = weld_vertices(self.vertices, self.faces, tolerance)
        _, first = np.unique(old_to_new[self.attachment], return_index=True)
        keep = np.sort(first)
        return Garment(self.kind, vertices, faces, old_to_new[self.attachment[keep]], self.attachment_part[keep])


def make_garment(kind: str, skel: Skeleton | None = None, max_edge: float = 0.08, seed: int = 0,
                 panels: bool = False) -> Garment:
    """Build a garment of `kind` for the skeleton's rest pose with every edge shorter than max_edge.

    The seed varies the design within a small range (ease, lengths). With `panels` the garment comes as separate
    panels with duplicated seam vertices (`_panel_seams`); every copy of an attachment vertex is attached, in the
    order of the whole garment's attachments, so that `welded` gives exactly the garment made without `panels`.
    Raises ValueError if max_edge is too coarse for the garment's openings or if the result would come closer
    than CLEARANCE to the body (a skeleton with proportions far from the default's).
    """
    if kind not in GARMENT_KINDS:
        raise ValueError(f"unknown garment kind '{kind}'; choose one of {', '.join(GARMENT_KINDS)}")
    if not max_edge > 0:
        raise ValueError(f"max_edge must be positive, got {max_edge}")
    body = RestMannequin(skel or default_skeleton())
    builder = _MeshBuilder(SPACING * max_edge)
    attachment, part = _BUILDERS[kind](body, builder, np.random.default_rng(seed))
    vertices, faces = builder.vertices, builder.faces
    if panels:
        vertices, faces, copied = cut_along_edges(vertices, faces, _panel_seams(body, vertices, faces))
        rank = np.full(len(builder.vertices), len(attachment))
        rank[attachment] = np.arange(len(attachment))
        copies = np.flatnonzero(rank[copied] < len(attachment))
        attachment = copies[np.argsort(rank[copied[copies]], kind="stable")]
    validate_mesh(vertices, faces)
    gap = body.distance(vertices)
    if gap.min() < CLEARANCE * body.scale:
        worst = int(np.argmin(gap))
        raise ValueError(f"{kind} does not fit this skeleton: vertex {worst} at {np.round(vertices[worst], 3)} is "
                         f"{gap[worst]:.4f} from the body (need {CLEARANCE * body.scale:.4f})")
    return Garment(kind=kind, vertices=vertices, faces=faces, attachment=np.asarray(attachment, dtype=np.int64),
                   attachment_part=np.full(len(attachment), body.skel.index(part), dtype=np.int64))


def _panel_seams(body: RestMannequin, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The seams (S, 2) of a garment sewn from about a dozen panels, along mesh edges. Horizontal seams at
    PANEL_SEAM_DEPTHS of its height split it into bands. The middle bands are quartered by centre-front,
    centre-back and side seams (the body's midplane and the coronal plane through the pelvis). Each piece of the
    top and bottom bands (waistband or yoke, hems and cuffs) gets a single seam at its own centre back: a band
    around the body stays one panel that meets itself along it, as a real waistband or cuff does, and an open
    band (a cape's) is split there or, where the jagged seam stops short, slit."""
    edges, sides = edge_faces(faces)
    interior = sides[:, 1] >= 0
    edges, a, b = edges[interior], sides[interior, 0], sides[interior, 1]
    centre = vertices[faces].mean(axis=1)
    top, bottom = vertices[:, 1].max(), vertices[:, 1].min()
    # A face's band is that of its highest corner: both triangles of a quad row whose top edge is within a
    # depth fall on its side, so the top band holds at least the first row however coarse the garment.
    band = np.digitize(top - vertices[faces, 1].max(axis=1), np.asarray(PANEL_SEAM_DEPTHS) * (top - bottom))
    same_band = band[a] == band[b]
    closed = same_band & ((band[a] == 0) | (band[a] == len(PANEL_SEAM_DEPTHS)))
    # The pieces of the top and bottom bands, each with its own centre.
    graph = sp.coo_matrix((np.ones(int(same_band.sum())), (a[same_band], b[same_band])), shape=(len(faces),) * 2)
    _, piece = csgraph.connected_components(graph, directed=False)
    piece_centre = np.stack([np.bincount(piece, weights=centre[:, k]) for k in range(3)], 1) / np.bincount(piece)[:, None]
    pelvis = body.joint("pelvis")
    middle = np.where(closed[:, None], piece_centre[piece[a]], pelvis)
    left_a, left_b = centre[a, 0] > middle[:, 0], centre[b, 0] > middle[:, 0]
    front_a, front_b = centre[a, 2] > middle[:, 2], centre[b, 2] > middle[:, 2]
    cut = ~same_band | ((left_a != left_b) & (~closed | ~front_a)) | ((front_a != front_b) & ~closed)
    return edges[cut]


# ---------------------------------------------------------------------------------------------------------------
# Geometry helpers


class RestMannequin:
    """The mannequin in its rest pose, which every garment is fitted around (and a garment from a file is dressed
    on, scenes.dressing): its capsules and joint positions, girths, distance queries and ring fitting."""

    def __init__(self, skel: Skeleton):
        self.skel = skel
        self.transforms = rest_transforms(skel)
        self.a, self.b, self.ra, self.rb = capsules_world(skel, self.transforms)
        self.scale = skel.height / 1.7

    def joint(self, name: str) -> np.ndarray:
        return self.transforms[1][self.skel.index(name)]

    def parts(self, *names: str) -> np.ndarray:
        return np.array([self.skel.index(n) for n in names])

    def distance(self, points: np.ndarray, parts: np.ndarray | None = None) -> np.ndarray:
        return body_signed_distance(self.skel, self.transforms, np.asarray(points).reshape(-1, 3), parts)

    def girth(self, name: str) -> float:
        """Around a horizontal torso capsule through its axis: two lengths of its segment and a circle."""
        p = self.skel.index(name)
        return float(2 * np.linalg.norm(self.b[p] - self.a[p]) + np.pi * (self.ra[p] + self.rb[p]))

    def nearest_part(self, points: np.ndarray, among: tuple[str, ...] | None = None) -> np.ndarray:
        """The part whose capsule is nearest each point, of the parts named `among` (default: all)."""
        parts = np.arange(self.skel.n_parts) if among is None else self.parts(*among)
        distance = capsule_signed_distance(np.asarray(points).reshape(-1, 3), self.a[parts], self.b[parts],
                                           self.ra[parts], self.rb[parts])
        return parts[distance.argmin(axis=1)].astype(np.int64)

    def lowest(self, name: str) -> float:
        p = self.skel.index(name)
        return float(min(self.a[p, 1] - self.ra[p], self.b[p, 1] - self.rb[p]))

    def fit(self, centers: np.ndarray, directions: np.ndarray, parts: np.ndarray, ease: float) -> np.ndarray:
        """For each centre (R, 3), the smallest scale s such that centre + t d is at least `ease` from the parts
        for every direction d (D, 3) and every t >= s. Sphere tracing inward from far outside stops at the
        outermost crossing of each ray (the distance is 1-Lipschitz, so a step never jumps past it)."""
        length = np.linalg.norm(directions, axis=1)
        t = np.full((len(centers), len(directions)), 2.0 * self.skel.height / length.min())
        for _ in range(200):
            points = centers[:, None, :] + t[..., None] * directions[None]
            gap = self.distance(points, parts).reshape(t.shape) - ease
            moving = (gap > 1e-5 * self.scale) & (t > 0.0)
            if not moving.any():
                break
            t = np.maximum(t - np.maximum(gap, 0.0) / length, 0.0)
        return t.max(axis=1)


class _MeshBuilder:
    """Accumulates vertices and the faces of quad grids."""

    def __init__(self, spacing: float):
        self.spacing = spacing
        self._points: list[np.ndarray] = []
        self._faces: list[np.ndarray] = []
        self._count = 0

    def add(self, points: np.ndarray) -> np.ndarray:
        """Append points (..., 3); returns their indices with the same leading shape."""
        points = np.asarray(points, dtype=np.float64)
        idx = self._count + np.arange(points.size // 3).reshape(points.shape[:-1])
        self._points.append(points.reshape(-1, 3))
        self._count += points.size // 3
        return idx

    @property
    def vertices(self) -> np.ndarray:
        return np.concatenate(self._points)

    @property
    def faces(self) -> np.ndarray:
        return np.concatenate(self._faces).astype(np.int64)

    def count(self, length: float, minimum: int = 1) -> int:
        """Number of grid intervals that keeps an interval of `length` within the spacing."""
        return max(minimum, int(np.ceil(length / self.spacing - 1e-9)))

    def grid(self, index: np.ndarray, wrap: bool = False) -> None:
        """Triangulate the quads of a (rows, cols) index grid, closing the columns into a ring if `wrap`.
        Outward is (column direction) x (row direction)."""
        if wrap:
            index = np.concatenate([index, index[:, :1]], axis=1)
        p = self.vertices
        v00, v01, v10, v11 = (index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(),
                              index[1:, 1:].ravel())
        main = np.linalg.norm(p[v00] - p[v11], axis=1) <= np.linalg.norm(p[v01] - p[v10], axis=1)
        first = np.where(main[:, None], np.stack([v00, v01, v11], 1), np.stack([v00, v01, v10], 1))
        second = np.where(main[:, None], np.stack([v00, v11, v10], 1), np.stack([v01, v11, v10], 1))
        self._faces.append(np.concatenate([first, second]))

    def tube(self, loop: np.ndarray, rings: np.ndarray, axis: np.ndarray) -> np.ndarray:
        """Add a tube whose first ring is the existing vertex loop `loop` (m,) and whose further rings are the
        new points `rings` (R, m, 3), advancing along `axis`. Returns the index grid (R + 1, m)."""
        p = self.vertices[loop]
        center = p.mean(axis=0)
        winding = np.einsum("ik,k->", np.cross(p - center, np.roll(p, -1, axis=0) - center), axis)
        if winding < 0:  # make the loop run counter-clockwise about the axis so the faces face outward
            loop, rings = loop[::-1], rings[:, ::-1]
        index = np.concatenate([loop[None], self.add(rings)])
        self.grid(index, wrap=True)
        return index


def _resample(polyline: np.ndarray, n: int, closed: bool = False) -> np.ndarray:
    """n + 1 points (n if closed) equally spaced by arc length along a dense polyline (..., D, 3)."""
    if closed:
        polyline = np.concatenate([polyline, polyline[..., :1, :]], axis=-2)
    seg = np.linalg.norm(np.diff(polyline, axis=-2), axis=-1)
    arc = np.concatenate([np.zeros(seg.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)
    targets = np.linspace(0.0, 1.0, n + 1)[:n] if closed else np.linspace(0.0, 1.0, n + 1)
    flat_poly = polyline.reshape(-1, polyline.shape[-2], 3)
    flat_arc = arc.reshape(-1, arc.shape[-1])
    out = np.stack([np.stack([np.interp(targets * a[-1], a, poly[:, k]) for k in range(3)], axis=-1)
                    for poly, a in zip(flat_poly, flat_arc)])
    return out.reshape(polyline.shape[:-2] + (len(targets), 3))


def _length(polyline: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(polyline, axis=-2), axis=-1).sum(axis=-1)


def _ring_template(rx: float, rz: float, exponent: float, n: int, dense: int = 720) -> np.ndarray:
    """n points (n, 3) of the superellipse |x/rx|^e + |z/rz|^e = 1 in the y = 0 plane, equally spaced by arc
    length, the first on +x and, n being a multiple of 4, the n/4-th on +z (so: counter-clockwise about -y)."""
    theta = 2 * np.pi * np.arange(dense) / dense
    c, s = np.cos(theta), np.sin(theta)
    dense_ring = np.stack([rx * np.sign(c) * np.abs(c) ** (2 / exponent), np.zeros(dense),
                           rz * np.sign(s) * np.abs(s) ** (2 / exponent)], axis=1)
    return _resample(dense_ring, n, closed=True)


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


def _bezier(start: np.ndarray, control: np.ndarray, end: np.ndarray, samples: int = 64) -> np.ndarray:
    """Dense quadratic Bezier curves (..., samples, 3) between per-column start/control/end points (..., 3)."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    return ((1 - t) ** 2 * start[..., None, :] + 2 * t * (1 - t) * control[..., None, :]
            + t ** 2 * end[..., None, :])


def _axis_point(chain: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Points at heights y on a polyline of joints running downward (e.g. hip, knee, ankle)."""
    ys = chain[::-1, 1]
    return np.stack([np.interp(y, ys, chain[::-1, k]) for k in range(3)], axis=-1)


# ---------------------------------------------------------------------------------------------------------------
# Pieces shared by several garments


class _Tube:
    """Rings of a horizontal tube around the torso: a superellipse template scaled per ring."""

    def __init__(self, body: RestMannequin, rx: float, rz: float, exponent: float = 3.0):
        self.body, self.rx, self.rz, self.exponent = body, rx, rz, exponent
        self.directions = _ring_template(rx, rz, exponent, 128)

    def fit(self, heights: np.ndarray, parts: np.ndarray, ease: float) -> np.ndarray:
        """Per height, the template scale that clears the parts by `ease`."""
        centers = self.body.joint("pelvis") * np.ones((len(heights), 1))
        centers[:, 1] = heights
        return self.body.fit(centers, self.directions, parts, ease)

    def count(self, builder: _MeshBuilder, largest_scale: float) -> int:
        """Vertices per ring (a multiple of 4) for the given largest template scale."""
        return 4 * builder.count(largest_scale * _length(np.concatenate([self.directions, self.directions[:1]]))
                                 / 4)

    def rings(self, heights: np.ndarray, scales: np.ndarray, n: int) -> np.ndarray:
        """Ring points (R, n, 3), vertex 0 on the left side (+x), n/4 in front, counter-clockwise about -y."""
        center = self.body.joint("pelvis")
        template = _ring_template(self.rx, self.rz, self.exponent, n)
        base = np.stack([np.full_like(heights, center[0]), heights, np.full_like(heights, center[2])], axis=1)
        return base[:, None, :] + scales[:, None, None] * template[None]


def _waist_tube(body: RestMannequin, builder: _MeshBuilder, top: float, bottom: float, ease: float,
                flare: float = 0.0) -> np.ndarray:
    """Tube from the waist at height `top` down to `bottom`, hugging pelvis and thighs with `ease` and never
    narrowing downward; below its widest fitted ring it flares by `flare` (radius gained per unit of drop).
    Returns the index grid (rows top to bottom, n)."""
    pelvis = body.skel.index("pelvis")
    rx = abs(body.a[pelvis, 0] - body.joint("pelvis")[0]) + body.ra[pelvis]
    tube = _Tube(body, rx, body.ra[pelvis])
    rows = builder.count(top - bottom)
    heights = np.linspace(top, bottom, rows + 1)
    scales = np.maximum.accumulate(tube.fit(heights, body.parts("pelvis", "spine", "thigh_l", "thigh_r"), ease))
    widest = heights[np.argmax(scales)]
    scales = scales + flare * np.maximum(widest - heights, 0.0) / rx
    index = builder.add(tube.rings(heights, scales, tube.count(builder, scales.max())))
    builder.grid(index, wrap=True)
    return index


def _sleeve(builder: _MeshBuilder, loop: np.ndarray, axis: np.ndarray, end_center: np.ndarray,
            end_radius: float, tilt: float) -> np.ndarray:
    """A tube from an armhole loop to a hem circle of `end_radius` around end_center, perpendicular to the arm
    `axis` but tilted so that its top lies `tilt` closer to the shoulder and its underside `tilt` farther: the
    armhole runs much farther up the shoulder than under the arm, and evening out the two lengths keeps the
    triangles of this single-topology tube well shaped. Loop vertices keep their angle about the arm, blended to
    equal spacing at the hem; rings in between interpolate linearly. Returns the index grid."""
    p = builder.vertices[loop]
    up = np.array([0.0, 1.0, 0.0])
    e1 = up - np.dot(up, axis) * axis
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    rel = p - end_center
    angle = np.unwrap(np.arctan2(rel @ e2, rel @ e1))
    m = len(loop)
    uniform = np.sign(angle[-1] - angle[0]) * 2 * np.pi * np.arange(m) / m
    uniform += np.mean(angle - uniform)
    end = (end_center + end_radius * (np.cos(uniform)[:, None] * e1 + np.sin(uniform)[:, None] * e2)
           - tilt * np.cos(uniform)[:, None] * axis)
    rows = builder.count(np.linalg.norm(end - p, axis=1).max())
    w = (np.arange(1, rows + 1) / rows)[:, None, None]
    return builder.tube(loop, (1 - w) * p + w * end, axis)


def _neckline(neck_point: np.ndarray, center: np.ndarray, neck_z: float) -> np.ndarray:
    """Dense half-ellipse from the left neck point through `center` (front or back) to the mirrored neck point."""
    psi = np.linspace(0.0, np.pi, 200)[:, None]
    return np.concatenate([neck_point[0] * np.cos(psi), neck_point[1] + (center[1] - neck_point[1]) * np.sin(psi),
                           neck_z + (center[2] - neck_z) * np.sin(psi)], axis=1)


def _upper_body(body: RestMannequin, builder: _MeshBuilder, torso_rings: np.ndarray, ease: float) -> dict:
    """Front and back panels from the top ring of the torso tube (index (n,), vertex 0 at the left armpit, n/4
    in front) up to the shoulder seams and neckline. Each panel column is a quadratic Bezier curve from the ring
    up to the top row, bulging forward (backward) enough to open the armholes around the arms. Returns the two
    armhole loops (left, right) and the shoulder seam vertices."""
    n = len(torso_rings)
    half = n // 2
    shoulder = body.joint("upper_arm_l")
    neck = body.joint("head")
    arm = body.skel.index("upper_arm_l")
    head = body.skel.index("head")
    s = body.scale
    shoulder_point = shoulder + np.array([0.02 * s, body.ra[arm] + ease + 0.01 * s, 0.0])
    neck_point = np.array([body.ra[head] + 0.04 * s, neck[1] + 0.04 * s, neck[2]])
    front_neck = np.array([0.0, neck[1] - 0.03 * s, neck[2] + 0.1 * s])
    back_neck = np.array([0.0, neck[1] + 0.02 * s, neck[2] - 0.075 * s])
    # Share the top row's columns between the shoulder seams and the neckline in proportion to their lengths.
    seam_length = np.linalg.norm(shoulder_point - neck_point)
    neck_length = _length(_neckline(neck_point, front_neck, neck[2]))
    seam = max(1, int(round(half * seam_length / (2 * seam_length + neck_length))))
    neckline = half - 2 * seam
    if neckline < 2:
        raise ValueError("garment too coarse for a neck opening: reduce max_edge")
    mirror = np.array([-1.0, 1.0, 1.0])

    def top_row(center: np.ndarray) -> np.ndarray:
        """Left seam, neckline through `center`, right seam: half + 1 points from the left shoulder point."""
        left = np.linspace(shoulder_point, neck_point, seam + 1)
        middle = _resample(_neckline(neck_point, center, neck[2]), neckline)
        return np.concatenate([left, middle[1:-1], left[::-1] * mirror])

    bottom = builder.vertices[torso_rings]
    front_top = top_row(front_neck)                     # columns 0..half, left to right across the front
    back_top = top_row(back_neck)[::-1]                 # columns half..n, right to left across the back
    bulge = 2 * (body.ra[arm] + ease)                   # the armhole's half-width is half the control's
    columns = []
    for sign, b, t in ((1.0, bottom[:half + 1], front_top), (-1.0, np.r_[bottom[half:], bottom[:1]], back_top)):
        control = 0.5 * (b + t)
        control[:, 1] = b[:, 1] + 0.7 * (t[:, 1] - b[:, 1])      # rise first, then turn over the shoulder
        control[:, 2] = sign * np.maximum(np.maximum(sign * b[:, 2], sign * t[:, 2]), bulge)
        columns.append(_bezier(t, control, b))
    rows = builder.count(max(_length(c).max() for c in columns), minimum=2)  # armholes need 4+ vertices
    front_pts, back_pts = (_resample(c, rows).transpose(1, 0, 2) for c in columns)  # (rows + 1, half + 1, 3)
    front = np.empty((rows + 1, half + 1), dtype=np.int64)
    back = np.empty_like(front)
    front[:rows] = builder.add(front_pts[:rows])
    front[rows] = torso_rings[:half + 1]
    back[rows] = np.r_[torso_rings[half:], torso_rings[:1]]
    back[1:rows] = builder.add(back_pts[1:rows])
    # Back top row: the shoulder seams reuse the front's vertices. Ring column c of the back lies opposite ring
    # column n - c of the front; the back grid's column j is ring column half + j, so front f meets back half - f.
    shared = np.r_[np.arange(seam + 1), np.arange(half - seam, half + 1)]
    back[0] = -1
    back[0, half - shared] = front[0, shared]
    open_cols = back[0] < 0
    back[0, open_cols] = builder.add(back_pts[0, open_cols])
    builder.grid(front)
    builder.grid(back)
    return {
        "armholes": (np.r_[front[:, 0], back[rows - 1:0:-1, -1]], np.r_[front[:, half], back[rows - 1:0:-1, 0]]),
        "shoulder": front[0, shared],
    }


# ---------------------------------------------------------------------------------------------------------------
# Garments: each adds its pieces to the builder and returns (attachment vertex indices, part they follow).


def _pants(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """Waist at the top of the pelvis, crotch seam 3 cm under it, legs down to just above the ankles."""
    s = body.scale
    ease = 0.025 * s * rng.uniform(0.85, 1.15)
    crotch = body.lowest("pelvis")
    waist = body.joint("pelvis")[1] + 0.05 * s
    junction = crotch + 0.01 * s
    hem = body.joint("foot_l")[1] + 0.03 * s * rng.uniform(0.8, 1.2)
    index = _waist_tube(body, builder, waist, junction, ease)
    ring = index[-1]
    n = len(ring)
    # Crotch seam: a U in the midplane x = 0 from the front centre of the lowest ring under the pelvis to the back.
    front, back = builder.vertices[ring[n // 4]], builder.vertices[ring[3 * n // 4]]
    u = np.linspace(0.0, 1.0, 200)[:, None]
    dip = junction - (crotch - 0.03 * s)
    curve = np.concatenate([np.zeros_like(u), junction - dip * np.sin(np.pi * u),
                            0.5 * (front[2] + back[2]) + 0.5 * (front[2] - back[2]) * np.cos(np.pi * u)], axis=1)
    seam = builder.add(_resample(curve, builder.count(_length(curve), minimum=2))[1:-1])  # front to back
    left = np.r_[ring[3 * n // 4:], ring[:n // 4 + 1], seam]
    right = np.r_[ring[n // 4:3 * n // 4 + 1], seam[::-1]]
    for side, loop in (("l", left), ("r", right)):
        _leg(body, builder, loop, side, junction, hem, ease)
    return index[0], "pelvis"


def _leg(body: RestMannequin, builder: _MeshBuilder, loop: np.ndarray, side: str, top: float, hem: float,
         ease: float) -> None:
    """A trouser leg from a loop at the crotch down to the hem: circles around the thigh and shin, never closer
    to the midplane than a quarter of the gap between the thighs (so the two legs do not touch), reached from the
    loop's shape over the first ~0.12 units."""
    s = body.scale
    chain = np.stack([body.joint(f"thigh_{side}"), body.joint(f"shin_{side}"), body.joint(f"foot_{side}")])
    thigh = body.skel.index(f"thigh_{side}")
    outward = np.sign(chain[0, 0])
    inner_limit = 0.5 * (abs(chain[0, 0]) - body.ra[thigh])   # half-way between the midplane and the thigh
    rows = builder.count(top - hem)
    heights = top - (top - hem) * np.arange(1, rows + 1) / rows
    centers = _axis_point(chain, heights)
    circle = _ring_template(1.0, 1.0, 2.0, 128)
    parts = body.parts(f"thigh_{side}", f"shin_{side}")
    radius = body.fit(centers, circle, parts, ease)
    radius = np.maximum(radius, body.rb[body.skel.index(f"shin_{side}")] + 1.5 * ease + 0.01 * s)
    shift = np.maximum(0.0, radius - (np.abs(centers[:, 0]) - inner_limit))
    centers[:, 0] += outward * shift
    p = builder.vertices[loop]
    rel = p - centers[0]
    angle = np.unwrap(np.arctan2(rel[:, 2], rel[:, 0]))
    m = len(loop)
    uniform = np.sign(angle[-1] - angle[0]) * 2 * np.pi * np.arange(m) / m
    uniform += np.mean(angle - uniform)
    blend = _smoothstep((top - heights) / (0.12 * s))[:, None]
    phi = (1 - blend) * angle + blend * uniform                                    # (rows, m)
    on_circle = centers[:, None, :] + radius[:, None, None] * np.stack(
        [np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=-1)
    lowered = p[None] + np.stack([np.zeros_like(heights), heights - top, np.zeros_like(heights)], 1)[:, None]
    builder.tube(loop, (1 - blend[..., None]) * lowered + blend[..., None] * on_circle, np.array([0.0, -1.0, 0.0]))


def _skirt(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """A-line skirt from the waist to just above the knees."""
    s = body.scale
    ease = 0.025 * s * rng.uniform(0.85, 1.15)
    waist = body.joint("pelvis")[1] + 0.05 * s
    hem = body.joint("shin_l")[1] + 0.06 * s * rng.uniform(0.5, 1.5)
    index = _waist_tube(body, builder, waist, hem, ease, flare=0.3 * rng.uniform(0.8, 1.2))
    return index[0], "pelvis"


def _torso(body: RestMannequin, builder: _MeshBuilder, hem: float, ease: float, flare: float) -> np.ndarray:
    """Torso tube from the armpits down to `hem` (top to bottom), straight around the chest, belly and hips,
    flaring below the hips by `flare`. Returns the index grid."""
    s = body.scale
    chest = body.skel.index("chest")
    armpit = body.joint("upper_arm_l")[1] - 0.15 * s
    tube = _Tube(body, abs(body.a[chest, 0]) + body.ra[chest], body.ra[chest])
    rows = builder.count(armpit - hem)
    heights = np.linspace(armpit, hem, rows + 1)
    torso_parts = body.parts("chest", "spine", "pelvis")
    hips = heights >= body.lowest("pelvis")
    fitted = tube.fit(heights[hips], torso_parts, ease)
    scales = np.full(len(heights), fitted.max())
    below = ~hips
    if below.any():
        legs = tube.fit(heights[below], body.parts("pelvis", "thigh_l", "thigh_r"), ease)
        drop = body.lowest("pelvis") - heights[below]
        scales[below] = np.maximum(legs, fitted.max() + flare * drop / tube.rx)
    index = builder.add(tube.rings(heights, scales, max(8, tube.count(builder, scales.max()))))
    builder.grid(index, wrap=True)
    return index


def _tshirt(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """Straight, loose tshirt down to the hips with short sleeves."""
    s = body.scale
    ease = 0.03 * s * rng.uniform(0.85, 1.15)
    torso = _torso(body, builder, body.joint("pelvis")[1] - 0.02 * s * rng.uniform(0.5, 1.5), ease, 0.0)
    upper = _upper_body(body, builder, torso[0], ease)
    for side, loop in zip("lr", upper["armholes"]):
        part = body.skel.index(f"upper_arm_{side}")
        axis = (body.b[part] - body.a[part]) / np.linalg.norm(body.b[part] - body.a[part])
        reach = ((builder.vertices[loop] - body.a[part]) @ axis).max() + 0.1 * s * rng.uniform(0.8, 1.2)
        end_center = body.a[part] + reach * axis
        radius = body.fit(end_center[None], _circle_around(axis, 64), body.parts(f"upper_arm_{side}"), ease)[0]
        _sleeve(builder, loop, axis, end_center, max(radius, body.ra[part] + 1.5 * ease), 0.03 * s)
    return upper["shoulder"], "chest"


def _dress(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """Sleeveless dress, straight over the torso, flaring from the hips to below the knees."""
    s = body.scale
    ease = 0.03 * s * rng.uniform(0.85, 1.15)
    hem = body.joint("shin_l")[1] - 0.05 * s * rng.uniform(0.5, 1.5)
    torso = _torso(body, builder, hem, ease, 0.3 * rng.uniform(0.8, 1.2))
    return _upper_body(body, builder, torso[0], ease)["shoulder"], "chest"


def _circle_around(axis: np.ndarray, n: int) -> np.ndarray:
    """n unit vectors perpendicular to `axis`."""
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = 2 * np.pi * np.arange(n) / n
    return np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2


def _cape(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """Hangs down the back from an arc that runs over both shoulders and behind the neck, widening downward."""
    s = body.scale
    arm = body.skel.index("upper_arm_l")
    shoulder = body.joint("upper_arm_l")
    top = shoulder[1] + body.ra[arm] + 0.04 * s
    half_width = shoulder[0] + 0.02 * s
    behind_neck = body.ra[body.skel.index("head")] + 0.05 * s
    back = -(body.ra[body.skel.index("chest")] + 0.05 * s)
    length = (top - body.joint("shin_l")[1] - 0.1 * s) * rng.uniform(0.9, 1.1)

    def surface(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """u in [-1, 1] from right (-x) to left (so outward is -z), v in [0, 1] from top to bottom."""
        drop = v * length
        wrap = _smoothstep(drop / (0.15 * s))   # from the arc around the neck to hanging flat behind the back
        x = u * (half_width + 0.15 * s * v)
        z = (1 - wrap) * (-behind_neck * np.sqrt(np.clip(1 - u * u, 0, 1))) + wrap * back
        return np.stack(np.broadcast_arrays(x, top - drop, z), axis=-1)

    dense = np.linspace(-1.0, 1.0, 200)
    cols = builder.count(max(_length(surface(dense, 0.0)), _length(surface(dense, 1.0))))
    paths = surface(np.linspace(-1.0, 1.0, cols + 1)[:, None], np.linspace(0.0, 1.0, 200)[None, :])
    index = builder.add(_resample(paths, builder.count(_length(paths).max())).transpose(1, 0, 2))
    builder.grid(index)
    return index[0], "chest"


def _patch(body: RestMannequin, builder: _MeshBuilder, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """A flat bib hanging in front of the chest and belly, held along its top edge."""
    s = body.scale
    chest = body.skel.index("chest")
    center = body.a[chest] * [0, 1, 1]
    front = body.ra[chest] + 0.03 * s
    width, height = 0.3 * s * rng.uniform(0.9, 1.1), 0.45 * s * rng.uniform(0.9, 1.1)
    cols, rows = builder.count(width), builder.count(height)
    x = np.linspace(width / 2, -width / 2, cols + 1)                 # left to right: outward is +z
    y = center[1] + 0.05 * s - np.linspace(0.0, height, rows + 1)
    xx, yy = np.meshgrid(x, y)
    index = builder.add(np.stack([xx, yy, np.full_like(xx, center[2] + front)], axis=-1))
    builder.grid(index)
    return index[0], "chest"


_BUILDERS = {"patch": _patch, "cape": _cape, "skirt": _skirt, "pants": _pants, "tshirt": _tshirt, "dress": _dress}
