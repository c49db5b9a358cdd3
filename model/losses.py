"""The paper's losses (section 3.6, eqs. 3-7) on vertex positions (B, V, 3).

The means run over every vertex (or face) of every sample in the batch, so a batch's loss is the loss of its
frames taken together; evaluation uses the same functions over a whole split.
"""
from __future__ import annotations

import dataclasses

import torch

# A face whose squared cross product is at most this (squared scene units, ~m^4: far below any real face's) is
# collapsed: it gets a zero normal and no gradient at all, instead of 0/0 or a 1/sqrt(eps) gradient that would
# swamp the optimiser's second moments.
_NORMAL_EPS2 = 1e-24


def l1_loss(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Eq. 4: mean over vertices of ||x^g - x^*||_1 / 3."""
    return _l1_terms(predicted, target).mean()


def l2_loss(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Eq. 5: sqrt(mean over vertices of ||x^g - x^*||_2^2)."""
    squared = _l2_terms(predicted, target).mean()
    # sqrt'(0) is infinite: an exact match must not turn the gradient into NaN.
    return torch.sqrt(squared.clamp_min(torch.finfo(squared.dtype).tiny))


def face_normals(positions: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Eq. 3: unit normals (B, F, 3) of counter-clockwise faces (F, 3); zero for a degenerate face."""
    x0, x1, x2 = (positions.index_select(-2, faces[:, k]) for k in range(3))
    cross = torch.linalg.cross(x1 - x0, x2 - x0, dim=-1)
    squared = cross.square().sum(dim=-1, keepdim=True)
    collapsed = squared <= _NORMAL_EPS2
    # rsqrt of a safe value where collapsed, so neither branch of the where() carries an inf or NaN gradient.
    return torch.where(collapsed, 0.0, cross * torch.rsqrt(torch.where(collapsed, 1.0, squared)))


def normal_loss(predicted: torch.Tensor, target: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Eq. 6: mean over faces of ||n^g - n^*||_1 / 3."""
    return _normal_terms(predicted, target, faces).mean()


def frame_terms(predicted: torch.Tensor, target: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(B, 3): each frame's L1, L2 squared and Ln, the means the losses above take over a whole batch taken
    frame by frame. Every frame has as many vertices and faces, so a batch's L1 (L2 squared, Ln) is the mean of
    its frames' (up to the order of the float sums): an evaluation sums them over a split a chunk at a time."""
    return torch.stack([_l1_terms(predicted, target).mean(dim=(1, 2)), _l2_terms(predicted, target).mean(dim=1),
                        _normal_terms(predicted, target, faces).mean(dim=(1, 2))], dim=1)


# What the losses average (the same elementwise arithmetic for a batch's loss and for frame_terms).
def _l1_terms(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return (target - predicted).abs()


def _l2_terms(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return (target - predicted).square().sum(dim=-1)


def _normal_terms(predicted: torch.Tensor, target: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    return (face_normals(target, faces) - face_normals(predicted, faces)).abs()


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Eq. 7's α, β, γ (paper section 5.1 uses 1, 0, 0; its decoder visuals 1, 1, 0.02)."""

    l1: float = 1.0
    l2: float = 0.0
    normal: float = 0.0


def total_loss(predicted: torch.Tensor, target: torch.Tensor, faces: torch.Tensor,
               weights: LossWeights) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Eq. 7: α L1 + β L2 + γ Ln, and the three terms (detached, whatever their weight) for logging."""
    terms = {"l1": l1_loss(predicted, target), "l2": l2_loss(predicted, target),
             "normal": normal_loss(predicted, target, faces)}
    total = weights.l1 * terms["l1"] + weights.l2 * terms["l2"] + weights.normal * terms["normal"]
    return total, {name: value.detach() for name, value in terms.items()}
