"""The losses (model/losses.py) on a mesh with zero-area faces (issue 14, item 6): finite values and gradients in
float32 and float64, gradients equal to central finite differences wherever the loss is differentiable, and a
degenerate face counted as a zero normal.

The mesh is model_meshes' 5 x 6 grid with two kinds of zero-area face: a band whose two rows of vertices
coincide (every face of the band has a zero-length edge) and a cap (a vertex moved onto the midpoint of the
opposite edge of one of its faces: three distinct collinear corners). Positions lie on a dyadic lattice (the grid
at 1/8, displacements at 1/1024), so that sums and cross products of them are exact in float32 and float64 and a
zero-area face stays exactly zero-area when displaced, as a real collapse would be.
"""
from __future__ import annotations

import pytest
import torch
from model_meshes import grid_mesh

from model.losses import LossWeights, face_normals, l1_loss, l2_loss, normal_loss, total_loss

ROWS, COLS = 5, 6
EVERY_TERM = LossWeights(l1=1.0, l2=1.0, normal=1.0)


def double_areas(positions: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """|cross product| of each face (..., F)."""
    corners = positions[..., faces, :]
    return torch.linalg.cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :],
                              dim=-1).norm(dim=-1)


def degenerate_grid() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Positions (V, 3) float64, faces (F, 3) and the corners of the cap (3,): its middle one lies on the segment
    between the other two."""
    vertices, faces = grid_mesh(ROWS, COLS)
    x = torch.round(torch.as_tensor(vertices, dtype=torch.float64) * max(ROWS, COLS)) / 8
    faces = torch.as_tensor(faces)
    row = torch.arange(COLS)
    x[2 * COLS + row] = x[1 * COLS + row]                  # the band between rows 1 and 2 collapses
    cap = faces[-1]                                         # a face of the last band, far from the collapsed one
    x[cap[1]] = 0.5 * (x[cap[0]] + x[cap[2]])
    return x, faces, cap


def moved(x: torch.Tensor, cap: torch.Tensor, seed: int, keep_degenerate: bool) -> torch.Tensor:
    """x plus a random displacement, 2 frames (B, V, 3); with `keep_degenerate` the coinciding rows move together
    and the cap's corners move alike, so the same faces keep zero area."""
    generator = torch.Generator().manual_seed(seed)
    noise = torch.round(0.05 * 1024 * torch.randn(2, *x.shape, generator=generator, dtype=x.dtype)) / 1024
    if keep_degenerate:
        row = torch.arange(COLS)
        noise[:, 2 * COLS + row] = noise[:, 1 * COLS + row]
        noise[:, cap] = noise[:, cap[:1]]
    return x + noise


def test_the_mesh_has_both_kinds_of_zero_area_face():
    x, faces, cap = degenerate_grid()
    zero = double_areas(x, faces) == 0
    assert zero.sum() == 2 * (COLS - 1) + 1 and zero[-1]
    kept = double_areas(moved(x, cap, 0, keep_degenerate=True), faces)
    assert (kept[:, zero] == 0).all() and (kept[:, ~zero] > 1e-4).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("degenerate", ["predicted", "target", "both"])
def test_every_loss_is_finite_with_finite_gradients(degenerate, dtype):
    x, faces, cap = degenerate_grid()
    predicted = moved(x, cap, 1, keep_degenerate=degenerate in ("predicted", "both")).to(dtype).requires_grad_()
    target = moved(x, cap, 2, keep_degenerate=degenerate in ("target", "both")).to(dtype)
    loss, terms = total_loss(predicted, target, faces, EVERY_TERM)
    loss.backward()
    assert torch.isfinite(loss) and all(torch.isfinite(t) for t in terms.values())
    assert torch.isfinite(predicted.grad).all()
    # A zero-area face has a zero normal (eq. 3 has none to give): exactly zero in both precisions.
    for positions, side in ((predicted.detach(), "predicted"), (target, "target")):
        flat = double_areas(positions, faces) == 0
        assert flat.sum() == (2 * (2 * (COLS - 1) + 1) if degenerate in (side, "both") else 0)
        assert (face_normals(positions, faces)[flat] == 0).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_collapsed_predicted_face_adds_no_gradient(dtype):
    """The normal term's gradient from collapsed faces is zero, not a 1/sqrt(eps) spike: with every collapsed face
    dropped from the mesh the gradient is the same (normal_loss averages over faces: scale by the face counts)."""
    x, faces, cap = degenerate_grid()
    predicted = moved(x, cap, 1, keep_degenerate=True).to(dtype)
    target = moved(x, cap, 2, keep_degenerate=False).to(dtype)
    flat = (double_areas(predicted, faces) == 0).any(dim=0)
    def gradient(kept_faces):
        p = predicted.clone().requires_grad_()
        (normal_loss(p, target, kept_faces) * len(kept_faces)).backward()
        return p.grad
    # Dropped faces still contribute |n*| - 0 to the loss, a constant: only the gradient is compared.
    torch.testing.assert_close(gradient(faces), gradient(faces[~flat]))
    assert gradient(faces).abs().max() < 1e3


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_an_exact_match_of_a_degenerate_mesh_has_zero_loss_and_zero_gradient(dtype):
    """The minimum: every term 0 (L2's sqrt and the zero normals included) and a zero gradient, not NaN."""
    x, faces, cap = degenerate_grid()
    target = moved(x, cap, 3, keep_degenerate=True).to(dtype)
    predicted = target.clone().requires_grad_()
    loss, terms = total_loss(predicted, target, faces, EVERY_TERM)
    loss.backward()
    assert loss.item() < 1e-15 and all(t.item() < 1e-15 for t in terms.values())
    assert (predicted.grad == 0).all()


def gradcheck_on(function, x: torch.Tensor, vertices: torch.Tensor) -> bool:
    """torch.autograd.gradcheck (central differences, float64) of `function` with respect to the positions of
    `vertices` only, the others held where x has them."""
    def of_subset(subset):
        full = x.detach().clone()
        full[:, vertices] = subset
        return function(full)
    return torch.autograd.gradcheck(of_subset, (x[:, vertices].detach().clone().requires_grad_(),), eps=1e-6,
                                    atol=1e-6, rtol=1e-4)


def test_l1_and_l2_gradients_match_finite_differences():
    x, faces, cap = degenerate_grid()
    predicted, target = moved(x, cap, 4, keep_degenerate=True), moved(x, cap, 5, keep_degenerate=True)
    every = torch.arange(len(x))
    assert gradcheck_on(lambda p: l1_loss(p, target), predicted, every)
    assert gradcheck_on(lambda p: l2_loss(p, target), predicted, every)


def test_normal_loss_gradient_matches_finite_differences_against_a_degenerate_target():
    """Zero-area faces in the target only: the loss is smooth in the predicted positions (a random displacement
    keeps every component of n_target - n_predicted clear of |.|'s kink), so every vertex is checked."""
    x, faces, cap = degenerate_grid()
    predicted, target = moved(x, cap, 6, keep_degenerate=False), moved(x, cap, 7, keep_degenerate=True)
    assert gradcheck_on(lambda p: normal_loss(p, target, faces), predicted, torch.arange(len(x)))


def test_normal_loss_gradient_matches_finite_differences_away_from_degenerate_predicted_faces():
    """Zero-area faces in the prediction: there the normal is defined as 0 and any move of a corner gives the face
    a unit normal, so a finite difference measures a jump, not a slope; that gradient is only required to be
    finite (above). Every vertex on no zero-area face is checked against finite differences."""
    x, faces, cap = degenerate_grid()
    zero = double_areas(x, faces) == 0
    predicted, target = moved(x, cap, 8, keep_degenerate=True), moved(x, cap, 9, keep_degenerate=False)
    on_degenerate = torch.zeros(len(x), dtype=torch.bool)
    on_degenerate[faces[zero].flatten()] = True
    clear = torch.nonzero(~on_degenerate).flatten()
    assert len(clear) >= len(x) // 3
    assert gradcheck_on(lambda p: normal_loss(p, target, faces), predicted, clear)


def test_a_degenerate_face_counts_as_a_zero_normal_in_the_loss():
    """The value the gradient is taken of: each zero-area predicted face adds |n_target|_1 / 3 / F to the normal
    loss, as a hand-made sum over faces says."""
    x, faces, cap = degenerate_grid()
    zero = double_areas(x, faces) == 0
    predicted, target = moved(x, cap, 10, keep_degenerate=True), moved(x, cap, 11, keep_degenerate=False)

    def unit_normals(positions):
        c = positions[:, faces]
        return torch.nn.functional.normalize(
            torch.linalg.cross(c[..., 1, :] - c[..., 0, :], c[..., 2, :] - c[..., 0, :], dim=-1), dim=-1)
    n_p, n_t = unit_normals(predicted), unit_normals(target)
    n_p[:, zero] = 0.0
    expected = (n_t - n_p).abs().sum(dim=-1).mean() / 3
    torch.testing.assert_close(normal_loss(predicted, target, faces), expected)
