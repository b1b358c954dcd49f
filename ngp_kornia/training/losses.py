"""Training targets and losses of the networks (Eq. 8-11 for ZSNet)."""

from __future__ import annotations

import math

import torch.nn.functional as F
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry import cossim, structure_tensor, weighted_structure_tensor

__all__ = ["zenith_labels", "zenith_classification_loss", "zenith_localisation_loss"]


def zenith_labels(
    zeniths: Tensor, zenith_gt: Tensor, mask: Tensor, positive_deg: float = 2.0, negative_deg: float = 5.0
) -> tuple[Tensor, Tensor]:
    """Candidate labels of Eq. 8: 1 within ``positive_deg`` of the true zenith (by cossim), 0 beyond
    ``negative_deg``, unlabelled in between.

    Args:
        zeniths: (B, Z, 3) candidates (pseudo camera).
        zenith_gt: (B, 3) true zenith in the same coordinates.
        mask: (B, Z) bool, False for invalid candidates (never labelled).
        positive_deg: delta_p.
        negative_deg: delta_n.

    Returns:
        labels (B, Z) float in {0, 1} and labelled (B, Z) bool.

    Example:
        >>> z = torch.tensor([[[0.0, 1.0, 0.0], [0.0, 1.0, 0.05], [1.0, 0.0, 0.0]]])
        >>> labels, labelled = zenith_labels(z, torch.tensor([[0.0, 1.0, 0.0]]), torch.ones(1, 3, dtype=torch.bool))
        >>> labels.tolist(), labelled.tolist()
        ([[1.0, 0.0, 0.0]], [[True, False, True]])
    """
    KORNIA_CHECK_SHAPE(zeniths, ["B", "Z", "3"])
    KORNIA_CHECK_SHAPE(zenith_gt, ["B", "3"])
    sim = cossim(zeniths, zenith_gt[:, None])
    positive = sim > math.cos(math.radians(positive_deg))
    negative = sim < math.cos(math.radians(negative_deg))
    return positive.to(zeniths), mask & (positive | negative)


def zenith_classification_loss(logits: Tensor, labels: Tensor, labelled: Tensor) -> Tensor:
    """Binary cross entropy of Eq. 9 over the labelled candidates (0 when none is labelled).

    Example:
        >>> labelled = torch.ones(1, 2, dtype=torch.bool)
        >>> zenith_classification_loss(torch.zeros(1, 2), torch.tensor([[1.0, 0.0]]), labelled)
        tensor(0.6931)
    """
    KORNIA_CHECK_SHAPE(logits, ["B", "Z"])
    per = F.binary_cross_entropy_with_logits(logits, labels, reduction="none") * labelled.to(logits)
    return per.sum() / labelled.sum().clamp_min(1)


def zenith_localisation_loss(scores: Tensor, zeniths: Tensor, mask: Tensor, zenith_gt: Tensor) -> Tensor:
    """Localisation loss of Eq. 10-11: Frobenius distance between the true zenith's structure tensor and the
    score-weighted mean structure tensor of the candidates, averaged over the batch.

    Args:
        scores: (B, Z) scores p_z in [0, 1] (differentiable).
        zeniths: (B, Z, 3) candidates.
        mask: (B, Z) bool.
        zenith_gt: (B, 3).

    Returns:
        scalar loss.

    Example:
        >>> z = torch.tensor([[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]])
        >>> ok = torch.ones(1, 2, dtype=torch.bool)
        >>> zenith_localisation_loss(torch.tensor([[1.0, 0.0]]), z, ok, torch.tensor([[0.0, 1.0, 0.0]]))
        tensor(0.)
    """
    KORNIA_CHECK_SHAPE(scores, ["B", "Z"])
    mean = weighted_structure_tensor(zeniths, scores * mask.to(scores))
    return (structure_tensor(zenith_gt) - mean).flatten(1).norm(dim=-1).mean()
