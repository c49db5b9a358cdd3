"""Linear blend skinning of garments to the mannequin: the Pose to Cloth predictor ("LBS of rest cloth").

Each vertex starts fully bound to the body part whose capsule is nearest in the rest pose; the weights are then
diffused over the garment's own mesh graph (uniform Laplacian smoothing), so that cloth crossing from one part
to the next (hip to thigh, chest to upper arm) blends them over about `blend_width`, while parts that are close
in space but not along the cloth (the other leg) never gain influence. Finally each row keeps its
`max_influences` largest weights, renormalised.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from geometry.mesh import unique_edges
from geometry.rotations import quat_conjugate, quat_multiply, quat_rotate, quat_to_matrix
from scenes.capsules import capsule_signed_distance, capsules_world
from scenes.kinematics import rest_transforms
from scenes.skeleton import Skeleton


def skinning_weights(skel: Skeleton, rest_vertices: np.ndarray, faces: np.ndarray, max_influences: int = 4,
                     blend_width: float = 0.08, smoothing_step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Influences (V, k) int64 part indices and weights (V, k) float64, k = min(max_influences, parts).

    Rows are sorted by decreasing weight and sum to 1; unused slots have weight 0. `blend_width` (a length for a
    1.7 tall body, scaled with the height) sets how far weights diffuse: each smoothing iteration moves every
    vertex's weights `smoothing_step` of the way to its neighbours' mean, and after n iterations they have
    spread over about sqrt(n step) mean edge lengths, so n follows from blend_width and the mesh resolution.
    """
    rest_vertices = np.asarray(rest_vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if max_influences < 1 or blend_width < 0 or not 0 < smoothing_step <= 1:
        raise ValueError(f"need max_influences >= 1, blend_width >= 0 and smoothing_step in (0, 1]; got "
                         f"{max_influences}, {blend_width}, {smoothing_step}")
    a, b, ra, rb = capsules_world(skel, rest_transforms(skel))
    nearest = capsule_signed_distance(rest_vertices, a, b, ra, rb).argmin(axis=1)
    return diffused_weights(nearest, skel.n_parts, rest_vertices, faces, blend_width * skel.height / 1.7,
                            max_influences, smoothing_step)


def diffused_weights(nearest: np.ndarray, n_parts: int, rest_vertices: np.ndarray, faces: np.ndarray,
                     width: float, max_influences: int = 4,
                     smoothing_step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex bound to its `nearest` part, the weights diffused over about `width` along the mesh and cut to
    the `max_influences` largest (see skinning_weights): influences (V, k) and weights (V, k)."""
    weights = np.zeros((len(rest_vertices), n_parts))
    weights[np.arange(len(rest_vertices)), nearest] = 1.0
    edges = unique_edges(faces)
    edge_length = np.linalg.norm(rest_vertices[edges[:, 0]] - rest_vertices[edges[:, 1]], axis=1).mean()
    neighbours = _neighbour_average(len(rest_vertices), edges)
    for _ in range(int(np.ceil((width / edge_length) ** 2 / smoothing_step))):
        weights = (1.0 - smoothing_step) * weights + smoothing_step * (neighbours @ weights)
    k = min(max_influences, n_parts)
    order = np.argsort(-weights, axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(weights, order, axis=1)
    return order.astype(np.int64), top / top.sum(axis=1, keepdims=True)


def rest_to_posed(rest_transforms: tuple[np.ndarray, np.ndarray],
                  transforms: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Affine maps (..., P, 3, 4) [R_p R0_p^T | t_p - R_p R0_p^T t0_p] carrying a rest-pose point rigidly with each
    part, from the rest part transforms (P, 4), (P, 3) to posed ones (..., P, 4), (..., P, 3)."""
    rest_rotation, rest_translation = rest_transforms
    rotation, translation = transforms
    relative = quat_multiply(rotation, quat_conjugate(rest_rotation))
    offset = translation - quat_rotate(relative, rest_translation)
    return np.concatenate([quat_to_matrix(relative), offset[..., None]], axis=-1)


def _neighbour_average(n_vertices: int, edges: np.ndarray) -> sp.csr_matrix:
    """Row-stochastic matrix averaging each vertex's mesh neighbours (uniform graph Laplacian smoothing)."""
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    adjacency = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    return sp.diags(1.0 / np.maximum(degree, 1.0)) @ adjacency


def linear_blend_skinning(rest_vertices: np.ndarray, indices: np.ndarray, weights: np.ndarray,
                          rest_transforms: tuple[np.ndarray, np.ndarray],
                          transforms: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Skinned positions (..., V, 3): sum_k w_k (R_p R0_p^T (x - t0_p) + t_p) over each vertex's influences p.

    rest_transforms are the part rotations (P, 4) and translations (P, 3) the weights were made for; transforms
    are the posed ones, (..., P, 4) and (..., P, 3) with any leading axes (e.g. frames). The per-vertex blended
    affine map is formed first, so memory is (..., V, 12) floats.
    """
    affine = rest_to_posed(rest_transforms, transforms)                                # (..., P, 3, 4)
    dense = np.zeros((len(rest_vertices), affine.shape[-3]))
    np.add.at(dense, (np.arange(len(rest_vertices))[:, None], indices), weights)
    blended = np.einsum("vp,...pij->...vij", dense, affine)
    return np.einsum("...vij,vj->...vi", blended[..., :3], rest_vertices) + blended[..., 3]
