"""Training targets and losses of the networks (Eq. 8-11 for ZSNet, Eq. 16-20 for FSNet)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry import (
    cossim,
    homogeneous_to_pseudo_camera,
    structure_tensor,
    weighted_structure_tensor,
)
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.metrics import frame_horizon_error

__all__ = [
    "zenith_labels",
    "zenith_classification_loss",
    "zenith_localisation_loss",
    "frame_labels",
    "frame_classification_loss",
]


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


def frame_labels(
    frames: FrameCandidates,
    zenith_gt: Tensor,
    horizon_gt: Tensor,
    height: int,
    width: int,
    sigma: float = 0.1,
    threshold: float = 0.5,
    horizon_scale: float = 1.0,
) -> tuple[Tensor, Tensor, Tensor]:
    r"""Target scores and labels of FSNet (Eq. 16-20).

    * :math:`s_z = \mathrm{cossim}(z_{gt}, z_i)`, both zeniths in the pseudo camera;
    * :math:`s_h = \exp(-\max(\|h_l - g_l\|_1, \|h_r - g_r\|_1)^2)` with the crossings of the candidate's
      horizon (from its zenith and focal length, :func:`frame_horizons`) and of the true horizon with the left and
      right image borders. The paper leaves the unit of the distance implicit; here it is
      :func:`frame_horizon_error`, in image heights (the unit of the usual horizon error), divided further by
      ``horizon_scale``. In pixels ``s_h`` would be about 0 for any error of a few pixels.
    * :math:`s_{vh} = \exp(-((s_h + s_z) / 2 - 1)^2 / (2 \sigma^2))` and :math:`c_i = [s_{vh} \ge \delta_s]`.

    With ``sigma = 0.1`` and ``threshold = 0.5`` a candidate is positive while :math:`(s_h + s_z) / 2 > 0.882`;
    for a correct zenith that is a horizon error below about 0.52 ``horizon_scale`` image heights.

    Args:
        frames: (B, F) candidates in the pseudo camera.
        zenith_gt: (B, 3) true zenith VP, homogeneous pixels.
        horizon_gt: (B, 3) true horizon line in pixels.
        height: image height in pixels.
        width: image width in pixels.
        sigma: sigma of Eq. 20.
        threshold: delta_s of Eq. 19.
        horizon_scale: unit of the horizon distance in image heights.

    Returns:
        ``s_vh`` (B, F), labels (B, F) float in {0, 1} (0 for invalid frames), valid (B, F) bool.

    Example:
        >>> fr = FrameCandidates(torch.tensor([[[0.0, 1.0, 0.0]]]), None, torch.ones(1, 1), None, None,
        ...                      torch.ones(1, 1, dtype=torch.bool))
        >>> s, c, ok = frame_labels(fr, torch.tensor([[0.0, 1.0, 0.0]]), torch.tensor([[0.0, 1.0, -239.5]]), 480, 640)
        >>> s, c, ok
        (tensor([[1.]]), tensor([[1.]]), tensor([[True]]))
    """
    KORNIA_CHECK_SHAPE(zenith_gt, ["B", "3"])
    z_gt = homogeneous_to_pseudo_camera(zenith_gt.to(frames.zenith), height, width)
    s_z = cossim(frames.zenith, z_gt[:, None])
    s_h = torch.exp(-((frame_horizon_error(frames, horizon_gt, height, width) / horizon_scale) ** 2))
    s_vh = torch.exp(-(((s_h + s_z) / 2 - 1) ** 2) / (2 * sigma**2))
    valid = torch.ones_like(s_vh, dtype=torch.bool) if frames.valid is None else frames.valid
    s_vh = torch.where(valid, s_vh, torch.zeros_like(s_vh))
    labels = ((s_vh >= threshold) & valid).to(s_vh)
    return s_vh, labels, valid


def frame_classification_loss(logits: Tensor, labels: Tensor, valid: Tensor) -> Tensor:
    """Binary cross entropy of FSNet (Eq. 18) averaged over the valid frames (0 when none is valid).

    Example:
        >>> valid = torch.tensor([[True, False]])
        >>> frame_classification_loss(torch.zeros(1, 2), torch.tensor([[1.0, 0.0]]), valid)
        tensor(0.6931)
    """
    KORNIA_CHECK_SHAPE(logits, ["B", "F"])
    per = F.binary_cross_entropy_with_logits(logits, labels.to(logits), reduction="none") * valid.to(logits)
    return per.sum() / valid.sum().clamp_min(1)
