"""Per-vertex inputs of the upsampling network that describe the coarse surface and the body around each vertex.

Absolute dataset-frame positions make an unseen pose an unseen input: trained on some motions, the network meets
new input values on a new motion (issue 11). The features here are relative to the local surface (normals, the
umbrella Laplacian), to time (velocity), to the body (distance and direction to the nearest capsule), or fixed per
vertex (rest positions), following Zhang & Li 2024 (Neural Garment Dynamic Super-Resolution).

Everything is batched torch: positions (B, V, 3) of the Loop-subdivided coarse mesh S x_low in the dataset's
frame (subdivided on the device from the low-res run, `FrameStore`), capsules (B, P, 3) in that same
frame. `InputFeatures` stacks the named features into the network's
(B, V, C) input; `FEATURE_CHANNELS` (model.feature_spec) says how many channels each name gives.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch
from torch import nn

from geometry.mesh import unique_edges
from model.feature_spec import FEATURE_CHANNELS, FeatureSpec, check_features
from model.local_frames import to_local, vertex_frames

# name -> the channels that hold a vector of the current frame, which turn with the local frame when inputs are
# local (rest positions name a material point, not a direction, so they stay as they are)
VECTOR_CHANNELS = {name: slice(0, 3) for name in ("position", "centered_position", "normal", "laplacian",
                                                   "velocity", "acceleration", "gravity", "previous_output")}
VECTOR_CHANNELS["body"] = slice(1, 4)

_EPS = 1e-12


@dataclasses.dataclass(frozen=True)
class FrameBatch:
    """What the features of a batch of frames are computed from, all in the dataset's frame.

    `previous` is S x_low at the previous frame of the same sequence (equal to `positions` at a sequence's first
    frame, which makes its velocity zero) and `before_previous` the previous frame's `previous` by the same rule;
    `gravity` is the unit gravity direction per frame (B, 3). `previous_output` is the displacement (x_high -
    S x_low) at the previous frame, zero at a sequence's first frame: the network's own output there when it runs
    frame after frame (model.autoregressive), the truth where a store holds it for statistics; None for a network
    that does not read it.
    """

    positions: torch.Tensor        # (B, V, 3)
    previous: torch.Tensor         # (B, V, 3)
    before_previous: torch.Tensor  # (B, V, 3)
    capsule_a: torch.Tensor        # (B, P, 3)
    capsule_b: torch.Tensor        # (B, P, 3)
    radius_a: torch.Tensor         # (P,)
    radius_b: torch.Tensor         # (P,)
    gravity: torch.Tensor          # (B, 3)
    frame_time: float              # seconds between frames
    previous_output: torch.Tensor | None = None   # (B, V, 3)


class Subdivider:
    """S x for batches of frames x (B, V_low, 3) -> (B, V_high, 3), S a sparse matrix given as CSR arrays.

    A padded gather and weighted sum over each row's entries (in the row's stored order) rather than a sparse
    matmul: it runs the same on the CPU and CUDA, inside a CUDA graph, and each output row's arithmetic does not
    depend on which other frames share the batch, so a frame's S x is the same bits however it is batched
    (streamed training equals resident training, model.streaming)."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, device: torch.device | str = "cpu"):
        counts = np.diff(indptr)
        width = max(int(counts.max(initial=0)), 1)
        columns, weights = np.zeros((len(counts), width), np.int64), np.zeros((len(counts), width), np.float32)
        slot = np.arange(len(indices)) - np.repeat(indptr[:-1], counts)
        row = np.repeat(np.arange(len(counts)), counts)
        columns[row, slot], weights[row, slot] = indices, data     # padding: column 0 with weight 0
        self.columns = torch.as_tensor(columns, device=device)
        self.weights = torch.as_tensor(weights, device=device)[None, :, :, None]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return (x[:, self.columns] * self.weights).sum(dim=2)


@dataclasses.dataclass(frozen=True)
class FrameStore:
    """Every frame of a dataset, from which batches of `FrameBatch` are gathered without copying each frame's
    history: `previous` (F,) is the id of each frame's previous frame in its sequence, its own id at a sequence's
    first frame. It holds the low-res run x_low and subdivides the frames a batch needs (`subdivide`, S x_low)
    on its device: S x_low is 15 times x_low's size at the paper's pants and is never stored."""

    low: torch.Tensor              # (F, V_low, 3) x_low
    subdivide: Subdivider          # S
    previous: torch.Tensor         # (F,) int64
    capsule_a: torch.Tensor        # (F, P, 3)
    capsule_b: torch.Tensor        # (F, P, 3)
    radius_a: torch.Tensor         # (P,)
    radius_b: torch.Tensor         # (P,)
    gravity: torch.Tensor          # (F, 3)
    frame_time: float
    # Each frame's true displacement (F, V_high, 3), where the store has them: a batch's previous_output is then
    # the truth at each frame's previous frame (what the input statistics are measured on; training and
    # evaluation replace it with the network's own, model.autoregressive).
    displacements: torch.Tensor | None = None

    def __len__(self) -> int:
        return len(self.low)

    def batch(self, ids: torch.Tensor) -> FrameBatch:
        previous = self.previous[ids]
        # One subdivision of the three rows of each frame (itself, its previous, the one before), in that order.
        rows = torch.cat([ids, previous, self.previous[previous]])
        positions, before, before_previous = self.subdivide(self.low[rows]).split(len(ids))
        return FrameBatch(positions, before, before_previous, self.capsule_a[ids], self.capsule_b[ids],
                          self.radius_a, self.radius_b, self.gravity[ids], self.frame_time,
                          None if self.displacements is None else self.previous_displacement(ids))

    def previous_displacement(self, ids: torch.Tensor) -> torch.Tensor:
        """The true displacement at each frame's previous frame (B, V_high, 3), zero at a sequence's first."""
        previous = self.previous[ids]
        first = (previous == ids)[:, None, None]
        return torch.where(first, torch.zeros((), device=ids.device), self.displacements[previous])

    def predictor(self, ids: torch.Tensor) -> torch.Tensor:
        """S x_low of the frames `ids` (B, V_high, 3): what the network's displacement is added to."""
        return self.subdivide(self.low[ids])


def previous_frames(sequence: np.ndarray) -> np.ndarray:
    """Previous-frame ids (F,) from per-frame sequence ids (F,) of frames stored in time order, sequence by
    sequence: f - 1 within a sequence, f itself at a sequence's first frame."""
    sequence = np.asarray(sequence)
    previous = np.arange(len(sequence)) - 1
    first = np.r_[True, sequence[1:] != sequence[:-1]] if len(sequence) else np.zeros(0, dtype=bool)
    if len(np.unique(sequence)) != int(first.sum()):
        raise ValueError("frames of a sequence must be stored contiguously (one run per sequence id)")
    previous[first] = np.flatnonzero(first)
    return previous


def vertex_normals(positions: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit vertex normals (B, V, 3): the sum of the incident faces' cross products (area-weighted), normalised.
    Faces are counter-clockwise seen from the side the normal points to."""
    x0, x1, x2 = (positions[:, faces[:, k]] for k in range(3))
    cross = torch.linalg.cross(x1 - x0, x2 - x0, dim=-1)
    summed = torch.zeros_like(positions)
    for k in range(3):
        summed.index_add_(1, faces[:, k], cross)
    return summed / summed.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def umbrella_laplacian(positions: torch.Tensor, edges: torch.Tensor, valence: torch.Tensor) -> torch.Tensor:
    """Mean of each vertex's neighbours minus the vertex (B, V, 3); `edges` (E, 2) undirected, `valence` (V,)."""
    summed = torch.zeros_like(positions)
    summed.index_add_(1, edges[:, 0], positions[:, edges[:, 1]])
    summed.index_add_(1, edges[:, 1], positions[:, edges[:, 0]])
    return summed / valence[:, None] - positions


def principal_stretches(positions: torch.Tensor, rest: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Principal stretches (B, V, 2), smaller first, of each vertex's incident faces against the rest mesh (V, 3),
    averaged over the faces weighted by rest area: 1 where undeformed, < 1 along a compressed direction (where
    the fine cloth wrinkles).

    Per face, with rest edge metric G and current metric g (2 x 2 Gram matrices of the two edges from corner 0),
    the squared stretches are the roots of det(g - s G) = 0.
    """
    def gram(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        e1, e2 = x[..., faces[:, 1], :] - x[..., faces[:, 0], :], x[..., faces[:, 2], :] - x[..., faces[:, 0], :]
        return (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)

    g11, g12, g22 = gram(positions)
    r11, r12, r22 = gram(rest)
    det_rest = r11 * r22 - r12 * r12
    half_trace = 0.5 * (g11 * r22 + g22 * r11 - 2.0 * g12 * r12) / det_rest    # (s1 + s2) / 2
    det = (g11 * g22 - g12 * g12) / det_rest                                    # s1 * s2
    root = (half_trace.square() - det).clamp_min(0.0).sqrt()
    stretches = torch.stack([(half_trace - root).clamp_min(0.0).sqrt(), (half_trace + root).sqrt()], dim=-1)
    area = det_rest.sqrt()                                                      # 2 x rest area
    summed = positions.new_zeros(positions.shape[0], positions.shape[1], 2)
    weight = positions.new_zeros(positions.shape[1])
    for k in range(3):
        summed.index_add_(1, faces[:, k], stretches * area[:, None])
        weight.index_add_(0, faces[:, k], area)
    return summed / weight[:, None]


def capsule_distances(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor, radius_a: torch.Tensor,
                      radius_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance (B, V, P) from points (B, V, 3) to each tapered capsule (B, P, 3 end points, (P,) radii;
    negative inside) and the unit outward surface normal at the closest surface point (B, V, P, 3), which is the
    distance's gradient.

    In the plane through the axis the surface is two circles joined by their common tangent; its outward normal
    leans by phi toward the thin end (sin phi = (r_a - r_b) / length). A point whose coordinates along that
    tangent fall before its contact with circle a (after the one with b) is nearest that sphere; any other point
    is nearest the tangent line (the same case split as scenes.capsules.capsule_signed_distance).
    """
    axis = b - a
    length = axis.norm(dim=-1)                                   # (B, P)
    unit = axis / length[..., None]
    rel = points[:, :, None, :] - a[:, None]                     # (B, V, P, 3)
    s = (rel * unit[:, None]).sum(-1)
    radial = rel - s[..., None] * unit[:, None]
    q = radial.norm(dim=-1)
    radial_unit = radial / q[..., None].clamp_min(_EPS)
    sin_phi = (radius_a - radius_b) / length                     # (B, P)
    cos_phi = torch.sqrt(1.0 - sin_phi.square())
    sin_phi, cos_phi, length = sin_phi[:, None], cos_phi[:, None], length[:, None]
    along = s * cos_phi - q * sin_phi
    rel_b = rel - axis[:, None]
    to_a, to_b = rel.norm(dim=-1), rel_b.norm(dim=-1)
    near_a, near_b = along <= 0.0, along >= length * cos_phi
    distance = torch.where(near_a, to_a - radius_a, torch.where(near_b, to_b - radius_b,
                                                                 s * sin_phi + q * cos_phi - radius_a))
    side_normal = sin_phi[..., None] * unit[:, None] + cos_phi[..., None] * radial_unit
    normal = torch.where(near_a[..., None], rel / to_a[..., None].clamp_min(_EPS),
                         torch.where(near_b[..., None], rel_b / to_b[..., None].clamp_min(_EPS), side_normal))
    return distance, normal


def nearest_capsule(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor, radius_a: torch.Tensor,
                    radius_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance (B, V) to the union of the capsules and the outward normal (B, V, 3) of the nearest one."""
    distance, normal = capsule_distances(points, a, b, radius_a, radius_b)
    nearest, which = distance.min(dim=-1)
    return nearest, normal.gather(2, which[..., None, None].expand(*which.shape, 1, 3)).squeeze(2)


def reference_neighbours(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """For each vertex, the next vertex of the first face that holds it: a fixed neighbour whose edge gives the
    vertex's local frame its tangent (model.local_frames)."""
    faces = np.asarray(faces, dtype=np.int64)
    corners, following = faces.ravel(), faces[:, [1, 2, 0]].ravel()
    vertices, first = np.unique(corners, return_index=True)
    if len(vertices) != n_vertices or vertices[-1] != n_vertices - 1:
        missing = np.setdiff1d(np.arange(n_vertices), vertices)
        raise ValueError(f"vertices {missing[:5].tolist()} belong to no face")
    return following[first]


class InputFeatures(nn.Module):
    """The network input (B, V, C) for the named features, stacked in `names` order.

    With `local_inputs`, vector features are expressed in each vertex's local frame (tangent, bitangent, normal of
    S x_low), so that they no longer depend on the garment's orientation; the normal then reads (0, 0, 1)
    everywhere and is refused. `frame_tangent` picks the frames' tangent: "edge" (each vertex's reference edge)
    or "gravity" (gravity projected onto the surface, smooth across vertices). The mesh's constants (faces, edges,
    rest positions, reference neighbours) are buffers, so they follow `.to(device)` and are saved with the model.
    """

    def __init__(self, names: tuple[str, ...], faces: np.ndarray, rest_positions: np.ndarray,
                 local_inputs: bool = False, frame_tangent: str = "edge"):
        super().__init__()
        check_features(names, local_inputs, frame_tangent)
        self.names, self.local_inputs, self.frame_tangent = tuple(names), local_inputs, frame_tangent
        n_vertices = len(rest_positions)
        edges = unique_edges(np.asarray(faces))
        valence = np.bincount(edges.ravel(), minlength=n_vertices)
        self.register_buffer("faces", torch.as_tensor(np.asarray(faces, dtype=np.int64)))
        self.register_buffer("edges", torch.as_tensor(edges))
        self.register_buffer("valence", torch.as_tensor(valence, dtype=torch.float32))
        self.register_buffer("rest", torch.as_tensor(np.asarray(rest_positions), dtype=torch.float32))
        self.register_buffer("reference", torch.as_tensor(reference_neighbours(faces, n_vertices)))

    @classmethod
    def of(cls, spec: FeatureSpec, faces: np.ndarray, rest_positions: np.ndarray) -> InputFeatures:
        """The features `spec` names on a mesh (its faces and subdivided rest positions)."""
        return cls(spec.inputs, faces, rest_positions, spec.input_frame == "local", spec.frame_tangent)

    @property
    def channels(self) -> int:
        return sum(FEATURE_CHANNELS[n] for n in self.names)

    def groups(self) -> list[int]:
        """Channel count of each feature, in stacking order (normalisation scales each group as one)."""
        return [FEATURE_CHANNELS[n] for n in self.names]

    def frames(self, inputs: FrameBatch) -> torch.Tensor:
        """Local frames (B, V, 3, 3) of S x_low (model.local_frames.vertex_frames)."""
        x = inputs.positions
        hint = inputs.gravity if self.frame_tangent == "gravity" else None
        return vertex_frames(x, vertex_normals(x, self.faces), self.reference, hint)

    def forward(self, inputs: FrameBatch) -> torch.Tensor:
        return self.with_frames(inputs, False)[0]

    def with_frames(self, inputs: FrameBatch, want_frames: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The features (B, V, C) and, where `want_frames`, the local frames (B, V, 3, 3), computed once for
        both (a network predicting in local frames turns its output back with the same frames)."""
        frames = self.frames(inputs) if self.local_inputs or want_frames else None
        columns = []
        for name in self.names:
            value = self._feature(name, inputs)
            if self.local_inputs and name in VECTOR_CHANNELS:
                value = value.clone()
                value[..., VECTOR_CHANNELS[name]] = to_local(frames, value[..., VECTOR_CHANNELS[name]])
            columns.append(value)
        return torch.cat(columns, dim=-1), frames if want_frames else None

    def _feature(self, name: str, inputs: FrameBatch) -> torch.Tensor:
        x = inputs.positions
        if name == "position":
            return x
        if name == "centered_position":
            return x - x.mean(dim=1, keepdim=True)
        if name == "rest_position":
            return self.rest.expand_as(x)
        if name == "normal":
            return vertex_normals(x, self.faces)
        if name == "laplacian":
            return umbrella_laplacian(x, self.edges, self.valence)
        if name == "velocity":
            return (x - inputs.previous) / inputs.frame_time
        if name == "acceleration":
            return (x - 2.0 * inputs.previous + inputs.before_previous) / inputs.frame_time ** 2
        if name == "strain":
            return principal_stretches(x, self.rest, self.faces) - 1.0
        if name == "body":
            distance, direction = nearest_capsule(x, inputs.capsule_a, inputs.capsule_b, inputs.radius_a,
                                                  inputs.radius_b)
            return torch.cat([distance[..., None], direction], dim=-1)
        if name == "previous_output":
            if inputs.previous_output is None:
                raise ValueError("the network reads its previous output: give FrameBatch.previous_output")
            return inputs.previous_output
        return inputs.gravity[:, None, :].expand_as(x)    # "gravity"
