r"""Line segments, homogeneous lines and their intersections (Eq. 2-4 of the paper), and the pseudo camera.

Segments are ``(B, N, 2, 2)`` tensors ``[[x0, y0], [x1, y1]]`` in pixels (x right, y down, origin at the centre of
the top-left pixel) with a ``(B, N)`` bool mask for padding. Homogeneous lines ``(a, b, c)`` satisfy
``a x + b y + c = 0``; homogeneous points may lie at infinity (third coordinate 0).
"""

from __future__ import annotations

import math

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from kornia.geometry.conversions import convert_points_to_homogeneous, normalize_points_with_intrinsics
from kornia.geometry.linalg import euclidean_distance
from torch import Tensor

from ngp_kornia.geometry.camera import image_center, intrinsics_matrix, normalize

#: the largest cross product of u and v taken for rounding residue, in units of eps * |u| |v|
_RESIDUE = 64.0

__all__ = [
    "cossim",
    "intersect_lines",
    "is_near_vertical",
    "pseudo_focal",
    "pseudo_intrinsics",
    "segment_lengths",
    "segments_to_lines",
    "homogeneous_to_pseudo_camera",
    "to_pseudo_camera",
]


def segment_lengths(segments: Tensor, mask: Tensor | None = None) -> Tensor:
    """Euclidean length of each segment (kornia's ``euclidean_distance``): (B, N, 2, 2) -> (B, N), zero where the
    (B, N) bool ``mask`` is False (padding) when one is given.

    Example:
        >>> segment_lengths(torch.tensor([[[[0.0, 0.0], [3.0, 4.0]], [[1.0, 1.0], [2.0, 2.0]]]]),
        ...                 torch.tensor([[True, False]]))
        tensor([[5., 0.]])
    """
    KORNIA_CHECK_SHAPE(segments, ["*", "2", "2"])
    lengths = euclidean_distance(segments[..., 1, :], segments[..., 0, :])
    return lengths if mask is None else lengths * mask.to(lengths)


def segments_to_lines(segments: Tensor) -> Tensor:
    r"""Homogeneous line through each segment, ``l = p_0 \times p_1`` (Eq. 2), scaled so ``a^2 + b^2 = 1``.

    A zero-length segment has no line and gives ``(0, 0, 0)``. Ours: kornia's lines are parametric
    (``ParametrizedLine.through``), not homogeneous, and it has no guard for the cross product's rounding residue.

    Args:
        segments: (B, N, 2, 2) segment endpoints.

    Returns:
        (B, N, 3) lines ``(a, b, c)`` with ``a x + b y + c = 0`` for both endpoints.

    Example:
        >>> segments_to_lines(torch.tensor([[[[0.0, 2.0], [5.0, 2.0]]]]))  # the line y = 2
        tensor([[[ 0.,  1., -2.]]])
    """
    KORNIA_CHECK_SHAPE(segments, ["*", "2", "2"])
    p = convert_points_to_homogeneous(segments)  # homogeneous endpoints (x, y, 1)
    cross = torch.linalg.cross(p[..., 0, :], p[..., 1, :])
    # zero a cross product that is only rounding residue of (anti)parallel inputs, so it is not normalised into a
    # random direction (fused multiply-adds leave about eps * |p0| |p1| where exact arithmetic gives 0); both
    # endpoints' norms come from one reduction, row by row as from two
    ends = torch.linalg.vector_norm(p, dim=-1, keepdim=True)
    tolerance = _RESIDUE * torch.finfo(p.dtype).eps * ends[..., 0, :] * ends[..., 1, :]
    line = torch.where(torch.linalg.vector_norm(cross, dim=-1, keepdim=True) <= tolerance, 0.0, cross)
    return line / torch.linalg.vector_norm(line[..., :2], dim=-1, keepdim=True).clamp_min(torch.finfo(line.dtype).eps)


def _residue_tolerance(u: Tensor, v: Tensor) -> Tensor:
    """The largest cross product of ``u`` and ``v`` (..., 3) taken for rounding residue (see :data:`_RESIDUE`)."""
    u_length = torch.linalg.vector_norm(u, dim=-1, keepdim=True)
    return _RESIDUE * torch.finfo(u.dtype).eps * u_length * torch.linalg.vector_norm(v, dim=-1, keepdim=True)


def intersect_lines(l0: Tensor, l1: Tensor) -> Tensor:
    r"""Intersection ``v = l_0 \times l_1`` of two homogeneous lines (Eq. 3), returned with unit norm.

    Parallel lines meet at a point at infinity (third coordinate 0); identical lines give ``(0, 0, 0)``. Ours:
    kornia intersects parametric lines with hyperplanes (``ParametrizedLine.intersect``), with no point at infinity.

    Args:
        l0: (..., 3) lines.
        l1: (..., 3) lines, broadcastable with ``l0``.

    Returns:
        (..., 3) homogeneous points of unit norm.

    Example:
        >>> intersect_lines(torch.tensor([1.0, 0.0, -2.0]), torch.tensor([0.0, 1.0, -3.0]))  # x=2, y=3
        tensor([0.5345, 0.8018, 0.2673])
    """
    KORNIA_CHECK_SHAPE(l0, ["*", "3"])
    KORNIA_CHECK_SHAPE(l1, ["*", "3"])
    l0, l1 = torch.broadcast_tensors(l0, l1)
    cross = torch.linalg.cross(l0, l1)
    norm = torch.linalg.vector_norm(cross, dim=-1, keepdim=True)
    # a cross product within the rounding residue is zeroed (as in segments_to_lines) before normalising, with the
    # norm computed once: a zeroed row divides to zero either way
    residue = norm <= _residue_tolerance(l0, l1)
    return torch.where(residue, 0.0, cross / norm.clamp_min(torch.finfo(cross.dtype).eps))


def is_near_vertical(lines: Tensor, threshold_deg: float = 67.5) -> Tensor:
    r"""Near-vertical line test of Eq. 4: the line's angle to the image x axis exceeds ``threshold_deg``. Ours:
    the paper's test on homogeneous lines, which kornia does not have.

    Args:
        lines: (..., 3) homogeneous lines.
        threshold_deg: :math:`\delta_z`, 67.5 degrees in the paper.

    Returns:
        (...,) bool.

    Example:
        >>> is_near_vertical(torch.tensor([[1.0, 0.1, 0.0], [0.1, 1.0, 0.0]]))
        tensor([ True, False])
    """
    KORNIA_CHECK_SHAPE(lines, ["*", "3"])
    # the direction of (a, b, c) is (-b, a): its angle to the x axis is atan(|a| / |b|)
    angle = torch.atan2(lines[..., 0].abs(), lines[..., 1].abs())
    return angle > math.radians(threshold_deg)


def cossim(x: Tensor, y: Tensor) -> Tensor:
    r"""Absolute cosine similarity of homogeneous vectors, :math:`|x \cdot y| / (\|x\| \|y\|)` (Eq. 8).

    Sign-free, so a homogeneous point and its negative are the same point. Zero vectors give 0. Ours: kornia has no
    cosine of homogeneous vectors, and torch's ``cosine_similarity`` keeps the sign.

    Args:
        x: (..., 3).
        y: (..., 3), broadcastable with ``x``.

    Returns:
        (...,) values in [0, 1].

    Example:
        >>> cossim(torch.tensor([0.0, 1.0, 0.0]), torch.tensor([0.0, -2.0, 0.0]))
        tensor(1.)
    """
    KORNIA_CHECK_SHAPE(x, ["*", "3"])
    KORNIA_CHECK_SHAPE(y, ["*", "3"])
    return (normalize(x) * normalize(y)).sum(-1).abs().clamp_max(1.0)


def pseudo_focal(height: int, width: int) -> float:
    """Focal length of the pseudo camera ``K_p``: half the long side, in pixels. Ours: the paper's pseudo camera.

    The paper states ``min(W, H) / 2``; half the long side (as in the authors' code) makes one unit span the same
    angle on landscape and portrait images of the same camera.

    Example:
        >>> pseudo_focal(480, 640)
        320.0
    """
    return max(height, width) / 2.0


def to_pseudo_camera(points: Tensor, height: int, width: int) -> Tensor:
    """Map pixel coordinates into the pseudo camera, ``K_p^-1 p``: centred on the image centre and divided by
    :func:`pseudo_focal`. Works on points (..., 2) and on segments (..., 2, 2) alike.

    This is :func:`kornia.geometry.conversions.normalize_points_with_intrinsics` with ``K_p``.

    Args:
        points: (..., 2) pixel coordinates.
        height: image height in pixels.
        width: image width in pixels.

    Returns:
        (..., 2) pseudo-camera coordinates.

    Example:
        >>> to_pseudo_camera(torch.tensor([[639.5, 239.5]]), 480, 640)
        tensor([[1., 0.]])
    """
    KORNIA_CHECK_SHAPE(points, ["*", "2"])
    return normalize_points_with_intrinsics(points, pseudo_intrinsics(height, width, points)[0])


def pseudo_intrinsics(height: int, width: int, like: Tensor, center: Tensor | None = None) -> Tensor:
    """The pseudo camera's ``K_p`` (B, 3, 3): focal length :func:`pseudo_focal`, principal point ``center`` (B, 2) (the
    image centre when omitted, B = 1), in the dtype and device of ``like``.

    Example:
        >>> pseudo_intrinsics(480, 640, torch.zeros(()))[0, 0]
        tensor([320.0000,   0.0000, 319.5000])
    """
    point = image_center(height, width, like=like)[None] if center is None else center.to(like)
    return intrinsics_matrix(point.new_full(point.shape[:1], pseudo_focal(height, width)), point)


def homogeneous_to_pseudo_camera(v: Tensor, height: int, width: int) -> Tensor:
    """Map homogeneous points (VPs, possibly at infinity) from pixels into the pseudo camera, ``K_p^-1 v``,
    returned with unit norm. Ours: kornia's ``normalize_points_with_intrinsics`` takes Euclidean points only.

    Args:
        v: (..., 3) homogeneous points in pixels.
        height: image height in pixels.
        width: image width in pixels.

    Returns:
        (..., 3) unit homogeneous points in pseudo-camera units.

    Example:
        >>> homogeneous_to_pseudo_camera(torch.tensor([639.5, 239.5, 1.0]), 480, 640)
        tensor([0.7071, 0.0000, 0.7071])
    """
    KORNIA_CHECK_SHAPE(v, ["*", "3"])
    c = image_center(height, width, like=v)
    xy = v[..., :2] - c * v[..., 2:]
    return normalize(torch.cat([xy, v[..., 2:] * pseudo_focal(height, width)], -1))
