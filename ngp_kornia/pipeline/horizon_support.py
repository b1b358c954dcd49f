"""Line support of horizon hypotheses (steps 1-4 of :mod:`ngp_kornia.pipeline.horizon`): the zenith refined by
least squares on its inlier segments, and for a hypothesised up vector the horizontal VPs along its horizon (peaks
of a histogram of where the non-vertical segments meet it) and the share of the segments' length its zenith and
those VPs explain (:mod:`~ngp_kornia.pipeline.line_kernel`'s closeness).
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from kornia.geometry.conversions import pol2cart
from torch import Tensor

from ngp_kornia.geometry import normalize, segment_lengths
from ngp_kornia.pipeline.constants import cached, numbers_like, rows_like
from ngp_kornia.pipeline.line_kernel import (
    CameraSegments,
    camera_segments,
    closeness_kernel,
    near_direction,
    total_length,
)

__all__ = ["horizon_support", "refine_up", "refine_up_on_camera", "support_on_camera", "up_from_pitch_roll"]


def up_from_pitch_roll(pitch: Tensor, roll: Tensor) -> Tensor:
    """Unit up vector in camera coordinates from pitch and roll in degrees; inverse of
    :func:`ngp_kornia.geometry.pitch_roll_from_up`.

    Args:
        pitch: (...) degrees, > 0 looking up.
        roll: (...) degrees.

    Returns:
        (..., 3) unit up vectors.

    Example:
        >>> up_from_pitch_roll(torch.tensor([0.0]), torch.tensor([0.0]))
        tensor([[ 0., -1.,  0.]])
    """
    p, r = torch.deg2rad(pitch), torch.deg2rad(roll)
    cos_p = torch.cos(p)
    return torch.stack([cos_p * torch.sin(r), -cos_p * torch.cos(r), torch.sin(p)], -1)


def refine_up(
    up: Tensor, segments: Tensor, mask: Tensor, K: Tensor, zenith_tol: float = 2.0, iterations: int = 2
) -> tuple[Tensor, Tensor]:
    """Least-squares up vector from the segments that point at the zenith ``K up`` within ``zenith_tol`` degrees.

    Args:
        up: (B, 3) initial unit up vectors (camera coordinates).
        segments: (B, N, 2, 2) pixels; mask: (B, N) bool; K: (B, 3, 3) intrinsics.
        zenith_tol: inlier angle in degrees.
        iterations: inlier selection and fit rounds.

    Returns:
        (B, 3) refined unit up vectors (the input where fewer than 3 inliers or the fit turned by more than 10
        degrees) and (B,) bool, True where refined.

    Example:
        >>> seg = torch.tensor([[[[0.0, 0.0], [0.0, 9.0]], [[5.0, 0.0], [5.0, 9.0]], [[9.0, 1.0], [9.0, 8.0]]]])
        >>> K = torch.tensor([[[10.0, 0.0, 5.0], [0.0, 10.0, 5.0], [0.0, 0.0, 1.0]]])
        >>> up, ok = refine_up(torch.tensor([[0.02, -1.0, 0.0]]), seg, torch.ones(1, 3, dtype=torch.bool), K)
        >>> up.round(decimals=4).tolist(), ok.tolist()
        ([[0.0, -1.0, 0.0]], [True])
    """
    return refine_up_on_camera(
        up, camera_segments(segments, K), segment_lengths(segments, mask), mask, zenith_tol, iterations
    )


def refine_up_on_camera(
    up: Tensor, cam: CameraSegments, lengths: Tensor, mask: Tensor, zenith_tol: float, iterations: int
) -> tuple[Tensor, Tensor]:
    """:func:`refine_up` on segments already in camera coordinates."""
    cos_tol = math.cos(math.radians(10.0))
    cur, ok = up, None
    for _ in range(iterations):
        inlier = near_direction(cam, cur, math.sin(math.radians(zenith_tol)) ** 2) & mask
        w = lengths * inlier
        M = torch.bmm(w[:, None] * cam.normals_t, cam.normals)  # sum_i w_i n_i n_i^T
        # a degenerate camera (a zero up vector, a singular K) makes M NaN, on which eigh fails outright: such an
        # image is not refined (a zero M has a defined decomposition)
        finite = torch.isfinite(M).flatten(1).all(-1)
        _, vecs = torch.linalg.eigh(torch.where(finite[:, None, None], M, torch.zeros_like(M)))
        fit = vecs[..., 0].detach()  # no gradient through eigh (unstable for close eigenvalues)
        dot = (fit * up).sum(-1, keepdim=True)
        fit = torch.where(dot < 0, -fit, fit)
        good = (inlier.sum(-1) >= 3) & (dot.abs()[:, 0] > cos_tol) & finite  # |dot|: fit . up
        cur = torch.where(good[:, None], fit, cur)
        ok = good if ok is None else ok | good
    return normalize(cur), torch.zeros(len(up), dtype=torch.bool, device=up.device) if ok is None else ok


def horizon_support(
    ups: Tensor,
    segments: Tensor,
    mask: Tensor,
    K: Tensor,
    num_peaks: int = 4,
    kernel_deg: float = 1.0,
    bins: int = 360,
    separation_deg: float = 3.0,
    zenith_ups: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Line support of horizon hypotheses and the horizontal VPs found along each.

    Args:
        ups: (B, H, 3) unit up vectors, one per hypothesis (the horizon is ``K^-T up``).
        segments: (B, N, 2, 2) pixels; mask: (B, N) bool; K: (B, 3, 3) intrinsics.
        num_peaks: horizontal VPs kept per horizon.
        kernel_deg: width of the closeness kernel, degrees.
        bins: histogram bins over the horizontal directions (180 degrees).
        separation_deg: least angle between two kept horizontal directions.
        zenith_ups: (B, H, 3) up vectors whose zenith ``K u`` explains the vertical segments of each hypothesis;
            ``ups`` when omitted. With a fixed focal length the zenith's distance and the horizon's offset are tied
            (``f^2 = s d``); separating them lets the horizontal VPs alone place the horizon when ``f`` is off.

    Returns:
        support (B, H) in [0, 1] (0 without segments), the horizontal VP directions (B, H, P, 3) in camera
        coordinates (unit, orthogonal to the hypothesis' up) and their histogram weights (B, H, P), strongest first
        (0 for an empty peak).
    """
    lengths = segment_lengths(segments, mask)
    return support_on_camera(
        ups,
        camera_segments(segments, K),
        lengths,
        total_length(lengths),
        num_peaks,
        kernel_deg,
        bins,
        separation_deg,
        zenith_ups,
    )


def support_on_camera(
    ups: Tensor,
    cam: CameraSegments,
    lengths: Tensor,
    total: Tensor,
    num_peaks: int,
    kernel_deg: float,
    bins: int,
    separation_deg: float,
    zenith_ups: Tensor | None,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`horizon_support` on segments already in camera coordinates (:func:`camera_segments`), their lengths
    (B, N) 0 where masked (so the closeness needs no mask) and ``total`` (B, 1) their sum (:func:`total_length`)."""
    B, H, _ = ups.shape
    kz = closeness_kernel(cam, (ups if zenith_ups is None else zenith_ups)[:, :, None], kernel_deg, None)  # (B, H, N)
    e1, e2 = _horizontal_basis(ups)
    index, meets = _directions(ups, e1, e2, cam.normals_t, bins)
    zero, one = numbers_like(kz, 0.0, 1.0)
    weight = lengths[:, None] * (one - kz) * meets
    hist = torch.zeros(B, H, bins, dtype=ups.dtype, device=ups.device).scatter_add_(-1, index, weight)
    hist = _smooth(hist)
    # keep separated local maxima
    half = max(1, round(separation_deg / 180.0 * bins))
    local_max = F.max_pool1d(_wrap(hist, half).reshape(B * H, 1, -1), 2 * half + 1, stride=1).reshape(B, H, bins)
    peaks = torch.where(hist >= local_max, hist, zero)
    value, idx = peaks.topk(min(num_peaks, bins), dim=-1)
    cos_sin = _bin_angles(bins, ups)[idx]  # (B, H, P, 2)
    dirs = cos_sin[..., :1] * e1[:, :, None] + cos_sin[..., 1:] * e2[:, :, None]  # (B, H, P, 3)
    kh = closeness_kernel(cam, dirs, kernel_deg, None, value > zero)  # (B, H, N)
    explained = torch.maximum(kz, kh)
    support = (explained * lengths[:, None]).sum(-1) / total
    return support, dirs, value


def _directions(ups: Tensor, e1: Tensor, e2: Tensor, nt: Tensor, bins: int) -> tuple[Tensor, Tensor]:
    """The histogram bin (B, H, N) of every segment's horizontal direction on each horizon and whether its line
    meets the horizon (B, H, N) bool."""
    # each segment's line meets the horizon in the horizontal direction n x u; with (e1, e2, u) right-handed its
    # coordinates are (n . e2, -n . e1), and |n x u|^2 = 1 - (n . u)^2
    pi, count, bound = numbers_like(ups, math.pi, bins, _meets_bound(ups.dtype))
    with torch.no_grad():  # integer bins and a bool: no gradient, so in place
        psi = torch.atan2(torch.bmm(e1, nt).neg_(), torch.bmm(e2, nt)).remainder_(pi)  # (B, H, N)
        index = psi.div_(pi).mul_(count).long().clamp_(0, bins - 1)
        meets = torch.bmm(ups, nt).square_() < bound  # 1 - (n . u)^2 > 1e-12
    return index, meets


@functools.cache
def _meets_bound(dtype: torch.dtype) -> float:
    """The least ``x`` of ``dtype`` with ``1 - x > 1e-12`` false, so that ``x < bound`` is that test in one pass:
    ``1 - x`` falls with ``x`` (rounding keeps the order), so the test holds exactly below the bound."""

    def meets(x: Tensor) -> bool:
        return bool(x.neg().add(1.0) > 1e-12)

    up, down = torch.tensor([2.0], dtype=dtype), torch.tensor([0.0], dtype=dtype)
    bound = torch.tensor([1.0 - 1e-12], dtype=dtype)
    while meets(bound):
        bound = torch.nextafter(bound, up)
    while not meets(below := torch.nextafter(bound, down)):
        bound = below
    return bound.item()


def _smooth(hist: Tensor) -> Tensor:
    """The histograms (B, H, bins) smoothed circularly by (1, 2, 3, 2, 1) / 9, in place (``hist`` is consumed)."""
    bins, (three, nine) = hist.shape[-1], numbers_like(hist, 3.0, 9.0)
    wrap = _wrap(hist, 2)  # wrap[..., 2 + i - k] is hist rolled by k
    near = wrap[..., 1 : bins + 1] + wrap[..., 3 : bins + 3]
    # 3 h + 2 near as one add with alpha 2: doubling is exact, so a fused multiply-add rounds the same
    return torch.add(hist.mul_(three), near, alpha=2.0).add_(wrap[..., :bins]).add_(wrap[..., 4:]).div_(nine)


def _bin_angles(bins: int, like: Tensor) -> Tensor:
    """The cosine and sine (bins, 2) of every bin's centre angle ``(i + 1/2) pi / bins``, built once per dtype and
    device (the values the same arithmetic gives element by element)."""

    def build() -> Tensor:
        angle = (torch.arange(bins, device=like.device).to(like) + 0.5) * (math.pi / bins)
        return torch.stack(pol2cart(torch.ones_like(angle), angle), -1)

    return cached(("bins", bins, like.dtype, like.device), build)


def _wrap(x: Tensor, k: int) -> Tensor:
    """``x`` circularly padded by ``k`` on both sides of its last dimension (``k`` at most its length)."""
    return torch.cat([x[..., -k:], x, x[..., :k]], -1)


def _horizontal_basis(ups: Tensor) -> tuple[Tensor, Tensor]:
    """A basis ``e1, e2`` (B, H, 3) of each horizontal plane, ``(e1, e2, u)`` right-handed: ``e1`` along
    ``u x z`` (``u x x`` where ``u`` is the optical axis)."""
    ref, alt = rows_like(ups, [[[0.0, 0.0, 1.0]]], [[[1.0, 0.0, 0.0]]])  # (1, 1, 3): broadcast
    e1 = torch.linalg.cross(ups, ref)
    norm = torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    if not bool((norm > numbers_like(norm, 1e-6)[0]).all()):
        e1 = torch.where(norm > 1e-6, e1, torch.linalg.cross(ups, alt))
        norm = torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    e1 = normalize(e1)
    return e1, torch.linalg.cross(ups, e1)
