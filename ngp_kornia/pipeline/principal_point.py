"""The principal point from three vanishing points, under a prior towards the image centre.

Three orthogonal directions seen by a pinhole camera with square pixels vanish at three points whose triangle has
the principal point as its orthocentre (:func:`orthocentre`): each altitude is the image of the plane through the
camera centre orthogonal to a side's direction. The frame search assumes the principal point at the image centre,
so its three VPs are orthogonal there by construction; their triangle says nothing new. The evidence is in the
segments: the camera ``(R, f, c)`` is refitted to the segments that point at the frame's three VPs, with the
principal point free (:func:`estimate_principal_point`). For three finite VPs this is the orthocentre of the VPs
that fit the segments best; where a VP is far away (a level camera's zenith) the orthocentre slides along a line
and the fit leans on the prior.

The fit: segment ``i`` with midpoint ``m_i`` and direction ``s_i`` is an inlier of the VP ``v_j = K R e_j`` it
points at within ``inlier_deg``; its residual is the sine of the angle between ``s_i`` and the ray from ``m_i`` to
``v_j``, weighted by its length. Gauss-Newton on a small rotation, the log focal length and the principal point,
with the inliers chosen again each step; the line noise ``sigma^2`` is the weighted mean squared residual, and the
prior ``c ~ N(centre, (centre_std * H)^2)`` per axis is added to the normal equations, which also give the
estimate's standard deviation. With the prior's standard deviation 0 the centre is kept.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from torch import Tensor

from ngp_kornia.geometry import intrinsics_matrix

__all__ = ["PrincipalPoint", "estimate_principal_point", "joint_principal_point", "orthocentre"]

#: fewer inliers than this leave the principal point at the prior
MIN_INLIERS = 12
#: finite-difference step of the Jacobian (parameters are radians, log focal length and pixels)
_STEP = 1e-6


class PrincipalPoint(NamedTuple):
    """An estimated principal point.

    Attributes:
        point: (B, 2) ``(c_x, c_y)`` in pixels.
        std: (B, 2) its standard deviation per axis, pixels (the prior's where the segments gave no evidence).
    """

    point: Tensor
    std: Tensor


def orthocentre(vps: Tensor) -> Tensor:
    """The orthocentre of the triangle of three homogeneous VPs: the principal point of a square-pixel camera that
    sees them as orthogonal directions.

    Each altitude is the line through one VP along the normal of the opposite side (a point at infinity in the
    normal's direction), so VPs at infinity are allowed.

    Args:
        vps: (B, 3, 3) homogeneous VPs, one per row, in pixels.

    Returns:
        (B, 3) homogeneous point, unit norm (third coordinate near 0 where the altitudes are nearly parallel).

    Example:
        >>> K = torch.tensor([[[500.0, 0.0, 300.0], [0.0, 500.0, 250.0], [0.0, 0.0, 1.0]]])
        >>> R = torch.linalg.qr(torch.tensor([[[1.0, 0.3, 0.2], [0.1, 1.0, 0.4], [0.3, 0.2, 1.0]]]))[0]
        >>> h = orthocentre((K @ R).transpose(1, 2))
        >>> (h[:, :2] / h[:, 2:]).round(decimals=3)
        tensor([[300., 250.]])
    """
    altitudes = []
    for i in range(2):
        side = torch.linalg.cross(vps[:, (i + 1) % 3], vps[:, (i + 2) % 3])
        normal = torch.stack([side[:, 0], side[:, 1], torch.zeros_like(side[:, 0])], -1)
        altitudes.append(torch.linalg.cross(vps[:, i], normal))
    point = torch.linalg.cross(altitudes[0], altitudes[1])
    return point / torch.linalg.vector_norm(point, dim=-1, keepdim=True).clamp_min(torch.finfo(point.dtype).tiny)


def _camera(K0: Tensor, R0: Tensor, params: Tensor) -> tuple[Tensor, Tensor]:
    """``K`` (B, 3, 3) and ``R`` (B, 3, 3) of (B, 6) parameters: rotation vector, log focal scale, pp offset."""
    R = axis_angle_to_rotation_matrix(params[:, :3]) @ R0
    focal = K0[:, 0, 0] * params[:, 3].exp()
    return intrinsics_matrix(focal, K0[:, :2, 2] + params[:, 4:]), R


def _sines(K: Tensor, R: Tensor, mid: Tensor, direction: Tensor) -> Tensor:
    """(B, N, 3) signed sine of the angle between every segment and the ray from its midpoint to each VP."""
    vps = (K @ R).transpose(1, 2)  # (B, 3, 3) rows
    ray = vps[:, None, :, :2] - mid[:, :, None] * vps[:, None, :, 2:]  # (B, N, 3, 2)
    cross = direction[..., None, 0] * ray[..., 1] - direction[..., None, 1] * ray[..., 0]
    norms = torch.linalg.vector_norm(direction, dim=-1)[..., None] * torch.linalg.vector_norm(ray, dim=-1)
    return cross / norms.clamp_min(1e-12)


def _step(K0, R0, params, mid, direction, weights, assign, prior, offset):
    """One Gauss-Newton step: new (B, 6) parameters and the (B, 6, 6) normal matrix."""

    def residuals(p: Tensor) -> Tensor:
        sines = _sines(*_camera(K0, R0, p), mid, direction)
        return sines.gather(-1, assign[..., None])[..., 0] * weights.sqrt()

    r = residuals(params)
    eye = torch.eye(6, dtype=params.dtype, device=params.device)
    J = torch.stack([(residuals(params + _STEP * e) - r) / _STEP for e in eye], -1)  # (B, N, 6)
    count = (weights > 0).sum(-1).to(r)
    noise = (r.square().sum(-1) / (count - 6).clamp_min(1.0)).clamp_min(1e-12)  # sigma^2 of the lines
    A = J.transpose(1, 2) @ J / noise[:, None, None] + torch.diag_embed(prior) + 1e-9 * eye
    pulled = torch.cat([params[:, :4], params[:, 4:] + offset], -1)  # the prior's residual: from its mean
    g = (J.transpose(1, 2) @ r[..., None])[..., 0] / noise[:, None] + prior * pulled
    return params - torch.linalg.solve(A, g), A


def estimate_principal_point(
    K: Tensor,
    R: Tensor,
    segments: Tensor,
    mask: Tensor,
    prior_std: float,
    inlier_deg: float = 2.0,
    iterations: int = 5,
    prior_mean: Tensor | None = None,
) -> PrincipalPoint:
    """The principal point of the camera that best fits the segments of a frame's three VPs (module docstring).

    Args:
        K: (B, 3, 3) intrinsics of the frame (its principal point is where the fit starts).
        R: (B, 3, 3) its rotation.
        segments: (B, N, 2, 2) segments in pixels; mask: (B, N) bool.
        prior_std: the prior's standard deviation per axis, pixels (0: the centre is known).
        inlier_deg: a segment within this angle of a VP is its inlier, degrees.
        iterations: Gauss-Newton steps.
        prior_mean: (B, 2) the prior's mean, pixels; None: ``K``'s principal point.

    Returns:
        the :class:`PrincipalPoint`; where fewer than :data:`MIN_INLIERS` segments are inliers, the prior's mean
        and standard deviation.
    """
    K0, R0, seg = K.double(), R.double(), segments.double()
    B = len(K0)
    start = K0[:, :2, 2]
    centre = start if prior_mean is None else prior_mean.to(start).expand(B, 2)
    prior_std_t = torch.full((B, 2), float(prior_std), dtype=torch.float64, device=K0.device)
    if prior_std <= 0 or B == 0:
        return PrincipalPoint(centre.to(K.dtype), torch.zeros_like(centre).to(K.dtype))
    mid, direction = seg.mean(-2), seg[..., 1, :] - seg[..., 0, :]
    lengths = torch.linalg.vector_norm(direction, dim=-1) * mask
    scale = (lengths.sum(-1, keepdim=True) / mask.sum(-1, keepdim=True).clamp_min(1)).clamp_min(1e-12)
    prior = torch.zeros(B, 6, dtype=torch.float64, device=K0.device)
    prior[:, 4:] = 1.0 / prior_std**2
    params = torch.zeros(B, 6, dtype=torch.float64, device=K0.device)
    offset = start - centre  # the prior pulls the principal point start + params[:, 4:] towards the centre
    tolerance = math.sin(math.radians(inlier_deg))
    for _ in range(iterations):
        best, assign = _sines(*_camera(K0, R0, params), mid, direction).abs().min(-1)
        weights = lengths / scale * (best < tolerance)
        params, A = _step(K0, R0, params, mid, direction, weights, assign, prior, offset)
    enough = (weights > 0).sum(-1) >= MIN_INLIERS
    std = torch.linalg.inv(A).diagonal(dim1=-2, dim2=-1)[:, 4:].clamp_min(0).sqrt()
    point = torch.where(enough[:, None], start + params[:, 4:], centre)
    ok = enough[:, None] & torch.isfinite(point).all(-1, keepdim=True)
    point, std = torch.where(ok, point, centre), torch.where(ok, std, prior_std_t)
    return PrincipalPoint(point.to(K.dtype), std.to(K.dtype))


def joint_principal_point(
    points: Tensor, stds: Tensor, centre: Tensor, prior_std: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """One camera's principal point from each photo's own estimate ``points`` (P, 2) with ``stds`` (P, 2)
    (:func:`estimate_principal_point`, each under the prior
    ``N(centre, prior_std^2)`` per axis): the prior counted once and every photo's evidence, its posterior's
    precision less the prior's, added. Returns the point and its standard deviation, pixels.

    Example:
        >>> point, std = joint_principal_point(torch.tensor([[330.0, 240.0], [330.0, 240.0]]),
        ...                                    torch.full((2, 2), 6.0), torch.tensor([320.0, 240.0]), 12.0)
        >>> [round(v, 2) for v in point], [round(v, 2) for v in std]  # two photos' evidence: nearer, narrower
        ([331.43, 240.0], [4.54, 4.54])
    """
    points, stds, centre = points.double(), stds.double(), centre.double()
    if prior_std <= 0:
        return tuple(centre.tolist()), (0.0, 0.0)
    prior = 1.0 / prior_std**2
    evidence = (1.0 / stds.clamp_min(1e-6).square() - prior).clamp_min(0.0)  # (P, 2) each photo's own precision
    means = (points / stds.clamp_min(1e-6).square() - centre * prior) / evidence.clamp_min(1e-300)
    precision = prior + evidence.sum(0)
    point = (centre * prior + (evidence * torch.where(evidence > 0, means, 0.0)).sum(0)) / precision
    return tuple(point.tolist()), tuple(precision.rsqrt().tolist())
