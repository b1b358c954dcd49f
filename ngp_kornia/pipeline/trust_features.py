"""What the parser knows about its answer beyond its best score, per image (:class:`TrustFeatures`): whether a
clearly different horizon scored almost as well, whether the image's lines support a clearly different horizon
nearly as well (the horizon search), how far the top-k frames disagree, how many lines it saw and how many of them
support the chosen frame, and how noisy they are. :mod:`ngp_kornia.pipeline.trust` maps them to the trust fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import torch
from torch import Tensor

from ngp_kornia.geometry import (
    closeness,
    fov_from_focal,
    image_center,
    pitch_roll_from_up,
    pseudo_focal,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
    topk_weighted_average,
)
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.pipeline.constants import constant_tensors
from ngp_kornia.pipeline.horizon import Refinement, search_horizon
from ngp_kornia.pipeline.result import Calibration

__all__ = [
    "DIFFERENT_HORIZON",
    "RESIDUAL_INLIER",
    "SharedInputs",
    "TrustFeatures",
    "line_residual",
    "support_rival",
    "trust_features",
]


#: two frames whose horizons differ by more than this (image heights, at either border) count as different answers
DIFFERENT_HORIZON = 0.03


#: a segment within this angle (degrees) of one of the answer's VPs counts in :attr:`TrustFeatures.line_residual`
RESIDUAL_INLIER = 2.0


@dataclass
class TrustFeatures:
    """What the parser knows about one answer, per image (every field (B,), float).

    Attributes:
        score: final score of the best frame (``s_vh * m`` with FSNet, ``m`` without).
        manhattan: Manhattan score ``m`` (Eq. 21) of the best frame.
        ambiguity: best score among frames whose horizon differs from the answer's by more than
            :data:`DIFFERENT_HORIZON` image heights, divided by the best score (0: no rival, 1: a rival as good).
        horizon_spread: score-weighted RMS distance (image heights, worse border) of the top-k frames' horizons from
            the answer's.
        pitch_spread: score-weighted standard deviation of the top-k frames' pitch, degrees.
        roll_spread: the same for roll, degrees.
        fov_spread: the same for the vertical field of view, degrees.
        lines: number of line segments.
        vertical_share: share of the segments' length that points at the answer's vertical VP.
        horizontal_share: the smaller share of the two horizontal VPs.
        valid_share: share of the scored frame candidates that are valid.
        support_rival: the best line support of the horizon search (:func:`~ngp_kornia.pipeline.horizon.search_horizon`)
            among horizons more than :data:`DIFFERENT_HORIZON` image heights from the answer's, divided by the best
            support of all (0: no rival, 1: the lines support a clearly different horizon as well). Unlike
            ``ambiguity``, which compares the frames FSNet scored, it sees every pitch and focal length near the
            answer, in the image's own lines.
        line_residual: how noisy the image's lines are, degrees: the length-weighted RMS angle between each segment
            within :data:`RESIDUAL_INLIER` degrees of one of the answer's three VPs and the ray from its midpoint to
            that VP (about 0.5 on clean renders, 0.6 on renders with lens distortion, 0.7 on York Urban).
    """

    score: Tensor
    manhattan: Tensor
    ambiguity: Tensor
    horizon_spread: Tensor
    pitch_spread: Tensor
    roll_spread: Tensor
    fov_spread: Tensor
    lines: Tensor
    vertical_share: Tensor
    horizontal_share: Tensor
    valid_share: Tensor
    support_rival: Tensor
    line_residual: Tensor

    def as_dict(self) -> dict[str, Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _border_heights(lines: Tensor, height: int, width: int) -> Tensor:
    """(..., 3) pixel lines -> (..., 2) their y at the left and right borders, in image heights (finite)."""
    ab = torch.linalg.vector_norm(lines[..., :2], dim=-1).clamp_min(1e-12)
    sign = torch.where(lines[..., 1] < 0, -1.0, 1.0).to(lines) / ab
    a, b, c = (lines * sign[..., None]).unbind(-1)
    b = b.clamp_min(1e-6)
    (xs,) = constant_tensors(((-0.5, width - 0.5),), lines.dtype, lines.device)
    y = -(a[..., None] * xs + c[..., None]) / b[..., None]
    return (y / height).clamp(-100.0, 100.0)


def _frame_horizons(frames: FrameCandidates, height: int, width: int) -> Tensor:
    """Pixel horizon lines (B, F, 3) of pseudo-camera frames: ``K_p^-T diag(1/f^2, 1/f^2, 1) z``."""
    f = frames.focal.clamp_min(1e-6)
    z = frames.zenith
    ab = z[..., :2] / (f**2)[..., None]
    pf = pseudo_focal(height, width)
    cx, cy = image_center(height, width, like=ab)
    a, b = ab.unbind(-1)
    return torch.cat([ab / pf, (z[..., 2] - (cx * a + cy * b) / pf)[..., None]], -1)


def _horizon_gaps(answer: Tensor, others: Tensor, height: int, width: int) -> Tensor:
    """How far each of the (B, F, 3) pixel horizons ``others`` lies from the (B, 3) answer's: (B, F), image heights at
    the worse border (:func:`_border_heights`)."""
    if answer.dtype != others.dtype:
        mine, theirs = _border_heights(answer, height, width)[:, None], _border_heights(others, height, width)
    else:
        heights = _border_heights(torch.cat([answer[:, None], others], 1), height, width)  # one pass for both
        mine, theirs = heights[:, :1], heights[:, 1:]
    return (theirs - mine).abs().amax(-1)


class SharedInputs(NamedTuple):
    """Values the parser already computed in the same call, passed along so the trust fields do not compute them
    again (each equal to what :func:`trust_features` would compute from its own arguments).

    Attributes:
        lines: (B, N, 3) the segments' lines in the pseudo camera.
        lengths: (B, N) the segments' lengths in input pixels, zero where the mask is False.
        top_k_weights: (B, F) the top-k weights of the frames' scores (:func:`topk_weighted_average`).
    """

    lines: Tensor
    lengths: Tensor
    top_k_weights: Tensor


def _weighted_std(values: Tensor, weights: Tensor) -> Tensor:
    mean = (weights * values).sum(-1, keepdim=True)
    return ((weights * (values - mean).square()).sum(-1)).clamp_min(0.0).sqrt()


def trust_features(
    result: Calibration,
    frames: FrameCandidates,
    scores: Tensor,
    segments: Tensor,
    mask: Tensor,
    top_k: int = 8,
    kernel_angle: float = 89.0,
    shared: SharedInputs | None = None,
    refinement: Refinement | None = None,
    residual_vps: Tensor | None = None,
) -> TrustFeatures:
    """The features of :class:`TrustFeatures` for a batch.

    Args:
        result: the batched answer (its horizon is compared with the frames').
        frames: the scored frame candidates (pseudo camera), F per image.
        scores: (B, F) their final scores, zero where invalid.
        segments: (B, N, 2, 2) the segments in input pixels.
        mask: (B, N) bool.
        top_k: k of the top-k average.
        kernel_angle: width of the Manhattan score's kernel, degrees.
        shared: the same call's lines, lengths and top-k weights, when already computed; None computes them.
        refinement: the horizon search run on the frame search's answer
            (:func:`~ngp_kornia.pipeline.horizon.search_horizon`, as the parser runs it); None runs it on ``result``.
        residual_vps: (B, 3, 3) pixel VPs (rows) for ``line_residual``; None: the answer's (see the parser).

    Returns:
        :class:`TrustFeatures`, every field (B,), finite.
    """
    size = height, width = tuple(int(v) for v in result.image_size[0].tolist())
    valid = frames.valid
    scores = torch.where(valid, scores, 0.0)
    best_score, best = scores.max(-1)
    disagreement = _frame_disagreement(result.horizon, frames, scores, best_score, top_k, shared, size)
    best_vps = frames.vps.gather(1, best[:, None, None, None].expand(-1, 1, 3, 3))[:, 0]
    shares, manhattan = _line_support(best_vps, segments, mask, height, width, kernel_angle, shared)
    found = search_horizon(result, segments, mask) if refinement is None else refinement
    residual = line_residual(result.vps if residual_vps is None else residual_vps, segments, mask)
    evidence = [support_rival(found, result.horizon, height, width), residual]
    # every feature but the counts is cleaned at once: finite, and 0 for an image without a valid frame
    raw = [best_score, manhattan, *disagreement[:2], *disagreement[2].unbind(1), shares[:, 1]]
    raw += [torch.minimum(shares[:, 0], shares[:, 2]), *(t.to(best_score) for t in evidence)]
    cleaned = torch.nan_to_num(torch.stack(raw, 1).to(result.focal), nan=0.0, posinf=0.0, neginf=0.0)
    cleaned = torch.where(valid.any(-1, keepdim=True), cleaned, 0.0)
    counts = {"lines": mask.sum(-1).to(result.focal), "valid_share": valid.to(result.focal).mean(-1)}
    return TrustFeatures(**dict(zip(_CLEANED, cleaned.unbind(1), strict=True)), **counts)


#: the features of :func:`trust_features` in the order they are cleaned together
_CLEANED = (
    "score", "manhattan", "ambiguity", "horizon_spread", "pitch_spread", "roll_spread", "fov_spread",
    "vertical_share", "horizontal_share", "support_rival", "line_residual",
)  # fmt: skip


def line_residual(vps: Tensor, segments: Tensor, mask: Tensor) -> Tensor:
    """:attr:`TrustFeatures.line_residual` (B,) of the answer's (B, 3, 3) pixel VPs (rows) and the segments.

    The angles are taken as their sines (in radians): below :data:`RESIDUAL_INLIER` degrees the two differ by less
    than 0.02%, and squared sines need no square root, absolute value or arcsine per segment and VP."""
    seg = segments.to(vps)
    start, end = seg[..., 0, :], seg[..., 1, :]
    mid, direction = (start + end) * 0.5, end - start  # mean(-2)'s values (up to a zero's sign, squared away), faster
    ray = vps[:, None, :, :2] - vps[:, None, :, 2:] * mid[:, :, None]  # (B, N, 3, 2), towards each VP
    cross = direction[..., None, 0] * ray[..., 1] - direction[..., None, 1] * ray[..., 0]
    length_sq = direction.square().sum(-1)
    sine_sq = (cross.square() / (length_sq[..., None] * ray.square().sum(-1)).clamp_min(1e-24)).amin(-1)  # (B, N)
    weight = length_sq.sqrt() * (mask & (sine_sq < math.sin(math.radians(RESIDUAL_INLIER)) ** 2))
    mean_sq = (weight * sine_sq).sum(-1) / weight.sum(-1).clamp_min(1e-9)
    return torch.rad2deg(mean_sq.sqrt())


def _frame_disagreement(
    horizon: Tensor, frames: FrameCandidates, scores: Tensor, best_score: Tensor, top_k: int, shared, size
) -> tuple[Tensor, Tensor, Tensor]:
    """How far the scored frames disagree with the answer: ``ambiguity`` (B,), ``horizon_spread`` (B,) and the
    spreads (B, 3) of pitch, roll and field of view over the top-k frames (:class:`TrustFeatures`); ``horizon`` is
    the answer's (B, 3), ``size`` the image's (height, width)."""
    height, width = size
    valid = frames.valid
    gap = _horizon_gaps(horizon, _frame_horizons(frames, height, width), height, width)  # (B, F)
    ambiguity = _rival_share(scores, gap, best_score)  # scores: zero for invalid frames
    w = topk_weighted_average(scores, frames.focal, top_k, valid)[1] if shared is None else shared.top_k_weights
    horizon_spread = (w * gap.square()).sum(-1).sqrt()
    spreads = _weighted_std(torch.stack(_frame_angles(frames, height, width), 1), w[:, None])  # (B, 3)
    return ambiguity, horizon_spread, spreads


def support_rival(found: Refinement, horizon: Tensor, height: int, width: int) -> Tensor:
    """:attr:`TrustFeatures.support_rival` (B,) from the search's hypotheses and the answer's (B, 3) horizon."""
    support = found.hypothesis_support
    gap = _horizon_gaps(horizon, found.hypothesis_horizon, height, width)
    return _rival_share(support, gap, support.amax(-1))


def _rival_share(values: Tensor, gap: Tensor, best: Tensor) -> Tensor:
    """The best of the (B, F) ``values`` whose horizon lies more than :data:`DIFFERENT_HORIZON` from the answer's
    (``gap``, (B, F)), over ``best`` (B,): the ``ambiguity`` and ``support_rival`` of :class:`TrustFeatures`."""
    rival = torch.where(gap > DIFFERENT_HORIZON, values, 0.0).amax(-1)
    return rival / best.clamp_min(1e-9)


def _frame_angles(frames: FrameCandidates, height: int, width: int) -> tuple[Tensor, Tensor, Tensor]:
    """(B, F) pitch, roll and vertical field of view of every frame, degrees."""
    f = frames.focal.clamp_min(1e-6)
    z = frames.zenith
    up = torch.cat([z[..., :2] / f[..., None], z[..., 2:]], -1)
    up = up * torch.where(up[..., 1:2] > 0, -1.0, 1.0).to(up)
    pitch, roll = pitch_roll_from_up(up)
    return pitch, roll, fov_from_focal(f * pseudo_focal(height, width), height)


def _line_support(
    vps: Tensor, segments: Tensor, mask: Tensor, height: int, width: int, kernel_angle: float, shared=None
) -> tuple[Tensor, Tensor]:
    """Line-length shares (B, 3) of each of the (B, 3, 3) VPs, and (B,) the Manhattan share of all three."""
    if shared is None:
        lines = segments_to_lines(to_pseudo_camera(segments, height, width))
        lengths = segment_lengths(segments, mask)
    else:
        lines, lengths = shared.lines, shared.lengths
    close = closeness(lines, vps, kernel_angle)  # (B, 3, N)
    total = lengths.sum(-1).clamp_min(1e-9)
    shares = (close * lengths[:, None]).sum(-1) / total[:, None]
    return shares, (close.amax(1) * lengths).sum(-1) / total
