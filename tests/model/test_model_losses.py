"""Losses (paper eqs. 3-7) on hand-made cases with known values."""
from __future__ import annotations

import math

import torch

from model.losses import LossWeights, face_normals, l1_loss, l2_loss, normal_loss, total_loss

TRIANGLE = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])   # normal +z
FACES = torch.tensor([[0, 1, 2]])


def test_l1_and_l2_by_hand():
    target = torch.zeros(1, 2, 3)
    predicted = torch.tensor([[[3.0, 0.0, 4.0], [0.0, 0.0, 0.0]]])
    # L1 = mean over the 2 vertices of ||d||_1 / 3 = ((3 + 4) / 3 + 0) / 2
    assert math.isclose(l1_loss(predicted, target).item(), 7 / 6, rel_tol=1e-6)
    # L2 = sqrt(mean of ||d||^2) = sqrt((25 + 0) / 2)
    assert math.isclose(l2_loss(predicted, target).item(), math.sqrt(12.5), rel_tol=1e-6)


def test_l2_is_finite_with_finite_gradient_at_exact_match():
    predicted = torch.ones(1, 4, 3, requires_grad=True)
    loss = l2_loss(predicted, torch.ones(1, 4, 3))
    loss.backward()
    assert loss.item() < 1e-15 and torch.isfinite(predicted.grad).all()


def test_face_normal_of_ccw_triangle():
    torch.testing.assert_close(face_normals(TRIANGLE, FACES), torch.tensor([[[0.0, 0.0, 1.0]]]))
    scaled = face_normals(TRIANGLE * 1e-3, FACES)                      # small faces keep unit normals
    torch.testing.assert_close(scaled, torch.tensor([[[0.0, 0.0, 1.0]]]))


def test_normal_loss_of_flipped_and_tilted_faces():
    flipped = TRIANGLE[:, [0, 2, 1]]                                  # same points, normal -z
    # ||n_g - n*||_1 / 3 = |1 - (-1)| / 3
    assert math.isclose(normal_loss(flipped, TRIANGLE, FACES).item(), 2 / 3, rel_tol=1e-6)
    tilted = TRIANGLE.clone()
    tilted[0, 2] = torch.tensor([0.0, 1.0, 1.0])                      # normal (0, -1, 1)/sqrt2
    expected = (1 / math.sqrt(2) + abs(1 - 1 / math.sqrt(2))) / 3
    assert math.isclose(normal_loss(tilted, TRIANGLE, FACES).item(), expected, rel_tol=1e-6)


def test_collapsed_triangle_gives_no_nan():
    for collapsed in (torch.zeros(1, 3, 3),                                       # all three corners at one point
                      torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]])):   # collinear
        predicted = collapsed.clone().requires_grad_()
        loss, terms = total_loss(predicted, TRIANGLE, FACES, LossWeights(1.0, 1.0, 1.0))
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(predicted.grad).all()
        assert math.isclose(terms["normal"].item(), 1 / 3, rel_tol=1e-6)      # zero normal vs (0, 0, 1)


def test_total_is_the_weighted_sum():
    predicted = TRIANGLE + torch.tensor([0.1, -0.2, 0.3])
    predicted[0, 2, 2] += 0.5
    weights = LossWeights(l1=0.5, l2=2.0, normal=0.02)
    total, terms = total_loss(predicted, TRIANGLE, FACES, weights)
    expected = 0.5 * l1_loss(predicted, TRIANGLE) + 2.0 * l2_loss(predicted, TRIANGLE) \
        + 0.02 * normal_loss(predicted, TRIANGLE, FACES)
    torch.testing.assert_close(total, expected)
    assert terms["normal"] > 0 and set(terms) == {"l1", "l2", "normal"}
