"""A gravity prior: the camera's pitch and roll as an IMU measures them, with their standard deviation.

The prior enters the searches where they choose, never as an answer of its own (a phone's IMU is about as good as
the lines of a clear photo, so the lines still decide within its range):

* **Zenith candidates.** A zenith candidate's direction from the image centre is its roll whatever the focal
  length; candidates whose roll is off the prior's by more than ``gate`` standard deviations are dropped before the
  zenith estimate and the frames' draws (:func:`zenith_agreement`), unless that drops them all.
* **Frames.** Each frame candidate has a full up vector (its zenith and its focal length); its score is multiplied
  by ``exp(-max(0, t - g s)^2 / (2 s^2))`` with ``t`` the angle between its up vector and the prior's, ``s`` the
  prior's standard deviation combined with :data:`FLOOR_DEG` and ``g`` the :data:`GATE` (:func:`frame_agreement`):
  frames within the gate keep their score, frames far off lose it, so the top-k frames, and with them the focal
  length, come from frames that agree. Within the gate the lines alone decide: pulling the frames towards the
  prior's noisy pitch pulls their focal length with it (measured: York Urban's FoV error grew by half with a
  one-sigma weighting). A photo whose lines disagree with the prior is left with frames of low line support: a
  lower score, a lower confidence.
* **Horizon search.** Its hypotheses are kept within ``gate`` standard deviations of the prior
  (:func:`allowed_ups`, read by :func:`~ngp_kornia.pipeline.horizon.search_horizon`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ngp_kornia.pipeline.horizon_support import up_from_pitch_roll
from ngp_kornia.pipeline.priors import Priors

__all__ = [
    "FLOOR_DEG",
    "GATE",
    "allowed_ups",
    "frame_agreement",
    "gravity_frame_scores",
    "gravity_zenith_weights",
    "prior_up",
    "zenith_agreement",
]

#: standard deviations of the prior within which the zenith candidates and horizon hypotheses are kept
GATE = 3.0
#: degrees combined with the prior's standard deviation: how far a good frame's up vector strays from the truth
FLOOR_DEG = 0.5


def _per_image(values: list[float], like: Tensor) -> Tensor:
    """(B, 1) of one number per image, computed in float64 and rounded once to ``like``'s dtype (as a Python number
    in an operation with ``like`` is)."""
    return torch.tensor(values, dtype=torch.float64, device=like.device).to(like.dtype)[:, None]


def _gates(priors: Priors, like: Tensor) -> tuple[Tensor, Tensor]:
    """Per image (B, 1): :data:`GATE` times the prior's standard deviation combined with :data:`FLOOR_DEG`, and
    twice that deviation's square, degrees, for the B = ``len(like)`` images."""
    spreads = [math.hypot(std, FLOOR_DEG) for std in priors.each("gravity_std", len(like))]
    return _per_image([GATE * s for s in spreads], like), _per_image([2.0 * s**2 for s in spreads], like)


def prior_up(priors: Priors, like: Tensor) -> Tensor:
    """The prior's unit up vector of each image (B, 3) in camera coordinates, for the B = ``len(like)`` images, in
    ``like``'s dtype and device."""
    ups = priors.each("gravity", len(like))
    return torch.stack([up_from_pitch_roll(like.new_tensor(float(p)), like.new_tensor(float(r))) for p, r in ups])


def _angle_deg(up: Tensor, reference: Tensor) -> Tensor:
    """Angles (B, ...) in degrees between unit vectors (B, ..., 3) and each image's unit vector (B, 1, 3)."""
    cosine = (up * reference).sum(-1).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.acos(cosine))


def frame_agreement(frame_R: Tensor, priors: Priors) -> Tensor:
    """The factor (B, F) of each frame candidate's score: 1 within :data:`GATE` standard deviations of the prior
    (module docstring), falling as a Gaussian of one standard deviation beyond.

    Args:
        frame_R: (B, F, 3, 3) the frames' rotations (the pseudo camera's: the same as the camera's).
        priors: with ``gravity``, one for all images or one per image.
    """
    gate, width = _gates(priors, frame_R)
    angle = _angle_deg(-frame_R[..., :, 1], prior_up(priors, frame_R)[:, None])
    return torch.exp(-(angle - gate).clamp_min(0.0).square() / width)


def zenith_agreement(zenith: Tensor, priors: Priors) -> Tensor:
    """Which zenith candidates (B, Z, 3) (homogeneous, pseudo camera) point, from the image centre, within the gate
    of the prior's roll: (B, Z) bool. A candidate at the centre (the camera looks straight up or down) has no roll
    and is kept."""
    sign = torch.where(zenith[..., 1:2] > 0, -1.0, 1.0).to(zenith)  # the up vector points up in the image
    x, y = (zenith[..., :2] * sign).unbind(-1)
    roll = torch.rad2deg(torch.atan2(x, -y))
    prior_roll = _per_image([float(up[1]) for up in priors.each("gravity", len(zenith))], zenith)
    off = (roll - prior_roll + 180.0).remainder(360.0) - 180.0
    centred = torch.linalg.vector_norm(zenith[..., :2], dim=-1) < 1e-6 * zenith[..., 2].abs()
    return (off.abs() <= _gates(priors, zenith)[0]) | centred


def allowed_ups(ups: Tensor, priors: Priors) -> Tensor:
    """Which horizon hypotheses (B, ..., H, 3) unit up vectors lie within the gate of the prior: (B, ..., H) bool."""
    between = [1] * (ups.dim() - 2)  # each image's prior over all of its hypotheses
    reference = prior_up(priors, ups).view(len(ups), *between, 3)
    return _angle_deg(ups, reference) <= _gates(priors, ups)[0].view(len(ups), *between)


def gravity_zenith_weights(weights: Tensor, zenith: Tensor, priors: Priors | None) -> Tensor:
    """The zenith candidates' (B, Z) weights with those off the prior's roll set to 0 (:func:`zenith_agreement`),
    unless that leaves an image none; ``weights`` as they are without a gravity prior."""
    if priors is None or priors.gravity is None:
        return weights
    kept = weights * zenith_agreement(zenith, priors).to(weights)
    return torch.where(kept.sum(-1, keepdim=True) > 0, kept, weights)


def gravity_frame_scores(scores: Tensor, frame_R: Tensor, priors: Priors | None) -> Tensor:
    """The frames' (B, F) scores times their agreement with the prior (:func:`frame_agreement`); as they are
    without a gravity prior."""
    if priors is None or priors.gravity is None:
        return scores
    return scores * frame_agreement(frame_R, priors).to(scores)
