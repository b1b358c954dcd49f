"""The camera-space line kernel shared by the horizon search and the polish: segments in normalised camera
coordinates (``K^-1 p``) and the closeness of every segment to candidate vanishing directions.

The closeness of a segment to a direction ``v`` is the package's kernel (:func:`~ngp_kornia.geometry.vp.closeness_of`)
of ``sin^2 t``, ``t`` the image angle between the segment and the ray from its midpoint to ``v``:
``max(0, 1 - sin^2 t / (4 sin^2 sigma))``, 1 on the VP, 3/4 at ``sigma``, 0 beyond ``2 sigma``. The measure is
ours, not kornia's: kornia has no batched, masked segment-to-VP kernel. Every function is batched over B with the
segment mask.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from kornia.geometry.conversions import convert_points_to_homogeneous
from kornia.geometry.linalg import transform_points
from torch import Tensor

from ngp_kornia.geometry import closeness_of, normalize
from ngp_kornia.pipeline.constants import cached, numbers_like

__all__ = [
    "CameraSegments",
    "camera_points",
    "camera_segments",
    "camera_segments_at_scales",
    "camera_terms",
    "closeness_kernel",
    "near_direction",
    "scale_constants",
    "scaled_camera_segments",
    "scaled_focal",
    "squared_sines",
    "total_length",
]


class CameraSegments(NamedTuple):
    """Segments in normalised camera coordinates (:func:`camera_terms`): midpoints (B, N, 2), directions (B, N, 2) and
    unit interpretation-plane normals (B, N, 3); the terms every hypothesis is scored with, built once: each
    segment's line through its midpoint (unit normal, :func:`_line`) and the normals as (B, 3, N) matrices, and
    the midpoint terms ``(1, m_x, m_y, |m|^2)`` (B, 4, N) of :func:`_ratio`."""

    mid: Tensor
    direction: Tensor
    normals: Tensor
    line_t: Tensor
    mid_terms: Tensor
    normals_t: Tensor

    def rows(self, index: Tensor) -> CameraSegments:
        """The rows ``index`` of the terms a hypothesis is scored with; the midpoints, directions and normals, which
        scoring does not read, are left out (None)."""
        return CameraSegments(None, None, None, self.line_t[index], self.mid_terms[index], self.normals_t[index])


def camera_terms(mid: Tensor, direction: Tensor, normals: Tensor) -> CameraSegments:
    # the (B, k, N) terms are stacked as such, not transposed after (the same values, one copy less)
    square = mid.square().sum(-1)
    terms = torch.stack([torch.ones_like(square), mid[..., 0], mid[..., 1], square], -2)
    return CameraSegments(mid, direction, normals, _line(mid, direction), terms, normals.transpose(-1, -2).contiguous())


def _line(mid: Tensor, direction: Tensor) -> Tensor:
    """The line through each midpoint along its direction, ``(-s_y, s_x, s_y m_x - s_x m_y) / |s|`` (B, 3, N)."""
    tiny = torch.finfo(mid.dtype).tiny ** 0.5
    sx, sy = direction[..., 0], direction[..., 1]
    line = torch.stack([-sy, sx, sy * mid[..., 0] - sx * mid[..., 1]], -2)
    return line / torch.linalg.vector_norm(direction, dim=-1).unsqueeze(-2).clamp_min(tiny)


def camera_segments(segments: Tensor, K: Tensor) -> CameraSegments:
    """Segments in normalised camera coordinates ``K^-1 p`` (:class:`CameraSegments`). ``K^-1`` is a similarity for
    square pixels, so image angles are kept."""
    return camera_terms(*camera_points(segments, K))


def camera_points(segments: Tensor, K: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The midpoints, directions and unit plane normals of :func:`camera_segments`; a zero-length segment (padding)
    has no plane, and its normal is 0 (its cross product is rounding residue that normalising would blow up)."""
    # kornia's transform_points divides by K^-1's z, which is exactly 1 (K^-1's last row is exactly (0, 0, 1))
    xy = transform_points(torch.linalg.inv(K), segments.flatten(1, 2)).view_as(segments)
    cam = convert_points_to_homogeneous(xy)  # (B, N, 2, 3): (x, y, 1)
    mid, direction = xy.mean(-2), xy[..., 1, :] - xy[..., 0, :]
    cross = torch.linalg.cross(cam[..., 0, :], cam[..., 1, :])
    return mid, direction, normalize(torch.where((direction != 0).any(-1, keepdim=True), cross, 0.0))


def _ratio(cam: CameraSegments, vps: Tensor, inplace: bool = False) -> tuple[Tensor, Tensor]:
    """Numerator ``(|s x d| / |s|)^2`` and denominator ``|d|^2`` (B, V, N) of the squared sine of :func:`squared_sines`,
    with ``d = v_xy - m v_z`` the ray from each midpoint ``m`` to each VP ``v`` (B, V, 3); ``inplace`` (no
    autograd) reuses the products' memory. ``|d|^2`` is one product of per-VP terms ``(|v_xy|^2, -2 v_z v_x,
    -2 v_z v_y, v_z^2)`` with per-segment terms ``(1, m_x, m_y, |m|^2)`` (:class:`CameraSegments`)."""
    num = torch.bmm(vps, cam.line_t)
    num = torch.square(num, out=num if inplace else None)
    vxy, vz = vps[..., :2], vps[..., 2:]
    terms = torch.cat([vxy.square().sum(-1, keepdim=True), numbers_like(vz, -2.0)[0] * vz * vxy, vz.square()], -1)
    return num, torch.bmm(terms, cam.mid_terms)


def squared_sines(cam: CameraSegments, vps: Tensor) -> Tensor:
    """Squared sine of the image angle between every segment and the ray from its midpoint to every VP
    (normalised camera coordinates).

    Args:
        cam: the segments (:class:`CameraSegments`); vps: (B, ..., 3) directions (VPs at infinity allowed).

    Returns:
        (B, ..., N) in [0, 1]; a VP at the midpoint gives 1, a zero-length segment 0 (padding: mask it).
    """
    tiny = torch.finfo(vps.dtype).tiny ** 0.5
    num, den = _ratio(cam, vps.reshape(vps.shape[0], -1, 3))
    sin2 = torch.where(den > tiny, num / den.clamp_min(tiny), 1.0).clamp_max(1.0)
    return sin2.reshape(*vps.shape[:-1], -1)


def closeness_kernel(
    cam: CameraSegments, vps: Tensor, kernel_deg: float, mask: Tensor | None, keep: Tensor | None = None
) -> Tensor:
    """Closeness of every segment to the nearest of a group of VPs: the kernel
    (:func:`~ngp_kornia.geometry.vp.closeness_of`) of the squared sine of :func:`squared_sines`,
    ``max(0, 1 - sin^2 theta / (4 sin^2 sigma))`` with ``sigma`` = ``kernel_deg``: 1 on the VP, 3/4 at ``sigma``, 0
    beyond ``2 sigma``.

    Args:
        cam: the segments (:class:`CameraSegments`); vps: (B, H, P, 3), P VPs per group; mask: (B, N) bool, the segments
            that count (None: all, for a caller that weighs them by lengths 0 where masked; the closeness is finite
            and at least +0, so it then gives the same products); keep: (B, H, P) bool, the VPs that count (all
            when omitted).

    Returns:
        (B, H, N): the largest closeness over each group's kept VPs (0 where none is kept or masked).

    The values of :func:`squared_sines` and the closeness taken VP by VP, with fewer full-size passes (this dominates
    the search's time): the closeness falls with ``sin^2``, so the largest is that of the smallest ``sin^2``; the
    guard against a VP on a midpoint runs only where one is that close, and without autograd the arithmetic runs
    in place."""
    B, H, P, _ = vps.shape
    tiny = torch.finfo(vps.dtype).tiny ** 0.5
    v = vps.reshape(B, H * P, 3)
    grad = torch.is_grad_enabled() and (v.requires_grad or cam.line_t.requires_grad or cam.mid_terms.requires_grad)
    num, den = _ratio(cam, v, not grad)
    # tiny, a power of 2, is the same number in the tensor's dtype; a photo without segments has nothing to reduce
    if den.numel() and den.amin().item() > tiny:
        sin2 = torch.div(num, den, out=None if grad else num)
    else:
        sin2 = torch.where(den > tiny, num / den.clamp_min(tiny), 1.0)
    if keep is not None and not bool(keep.all()):
        sin2 = sin2.masked_fill(~keep.reshape(B, H * P, 1), math.inf)
    sin2 = sin2.view(B, H, P, -1).amin(2) if P > 1 else sin2.view(B, H, -1)
    out = closeness_of(sin2, kernel_deg, "squared_sine", inplace=not grad)
    if mask is None:
        return out
    return out * mask[:, None] if grad else out.mul_(mask[:, None])


def near_direction(cam: CameraSegments, up: Tensor, bound: float) -> Tensor:
    """``squared_sines(cam, up[:, None])[:, 0] <= bound`` (B, N) in fewer passes for ``bound`` below 1/2: where
    ``|d|^2 > tiny`` the squared sine is ``num / den`` (the clamp of ``den`` to tiny does nothing there; the clamp of
    the sine to 1 does nothing below ``bound``), elsewhere 1, never below."""
    if bound >= 0.5:
        return squared_sines(cam, up[:, None])[:, 0] <= bound
    with torch.no_grad():  # a bool: in place
        num, den = _ratio(cam, up[:, None], True)
        bound_t, tiny = numbers_like(den, bound, torch.finfo(den.dtype).tiny ** 0.5)
        return (torch.div(num, den, out=num)[:, 0] <= bound_t) & (den[:, 0] > tiny)


def total_length(lengths: Tensor) -> Tensor:
    """The total segment length (B, 1), at least tiny^0.5 (the support's denominator)."""
    return lengths.sum(-1, keepdim=True).clamp_min(torch.finfo(lengths.dtype).tiny ** 0.5)


def scaled_focal(K: Tensor, scale: Tensor) -> Tensor:
    """``K`` (B, 3, 3) with its focal length times ``scale`` (B,, K's dtype), the principal point kept."""
    entries = cached(
        ("focal entries", K.device),
        lambda: torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 0]], dtype=torch.bool, device=K.device),
    )
    return torch.where(entries, K * scale[:, None, None], K)


def scaled_camera_segments(cam: CameraSegments, inv: Tensor, stretch: Tensor) -> CameraSegments:
    """The segments seen with the focal length times each of S scales (:func:`scale_constants`), (S * B) rows,
    scale-major. ``K^-1`` with ``f`` times ``x`` maps the centred points to ``p / x``: midpoints and directions scale
    by ``1 / x``, and the plane normal ``(n_x, n_y, n_z)`` becomes ``(x n_x, x n_y, n_z)`` up to its length."""
    return _scaled(cam.mid, cam.direction, cam.normals, inv, stretch)


def _scaled(mid: Tensor, direction: Tensor, normals: Tensor, inv: Tensor, stretch: Tensor) -> CameraSegments:
    mid_s, direction_s = (mid * inv).flatten(0, 1), (direction * inv).flatten(0, 1)
    return camera_terms(mid_s, direction_s, normalize((normals * stretch).flatten(0, 1)))


def camera_segments_at_scales(
    segments: Tensor, K: Tensor, scales: list[float]
) -> tuple[CameraSegments, CameraSegments]:
    """The segments in camera coordinates (:func:`camera_segments`) and at every focal scale
    (:func:`scaled_camera_segments`), the first scale 1. Its rows' line and midpoint terms are the unscaled segments'
    (times 1 is exact), so those are built once; its normals are normalised again, so the unscaled ones are kept
    apart."""
    mid, direction, normals = camera_points(segments, K)
    _, inv, stretch = scale_constants(scales, K)
    scaled = _scaled(mid, direction, normals, inv, stretch)
    B = len(K)
    cam = CameraSegments(
        mid, direction, normals, scaled.line_t[:B], scaled.mid_terms[:B], normals.transpose(-1, -2).contiguous()
    )
    return cam, scaled


def scale_constants(scales: list[float], like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The focal scales (S,), their inverses (S, 1, 1, 1) and the stretch of the plane normals (S, 1, 1, 3)."""

    def build() -> tuple[Tensor, Tensor, Tensor]:
        inv = torch.tensor([1.0 / x for x in scales]).to(like)[:, None, None, None]
        stretch = torch.cat([1.0 / inv, 1.0 / inv, torch.ones_like(inv)], -1)
        return torch.tensor(scales, dtype=like.dtype, device=like.device), inv, stretch

    return cached(("scales", *scales, like.dtype, like.device), build)
