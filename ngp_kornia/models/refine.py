"""Horizon refinement in image space for Atlanta worlds: after the frame search, find every horizontal VP along
the horizon (one or two per building block, not only the frame's two) and move the horizon where the lines
support it best.

Method (all batched over B with the segment mask; no loop over images; about 3 ms of one CPU core per image with
512 segments):

1. **Zenith.** The up vector is refined by least squares on its inlier segments (those pointing at the zenith
   within ``zenith_tol`` degrees), weighted by length: the smallest eigenvector of ``sum_i L_i l_i l_i^T`` with
   ``l_i`` the unit normal of segment ``i``'s interpretation plane (Gaussian sphere), twice.
2. **Hypotheses.** A horizon with a centred principal point and the frame's focal length ``f`` is fixed by the up
   vector ``u`` (the line ``K^-T u``, the polar of the zenith ``K u`` with respect to the image of the absolute
   conic): roll gives its angle, pitch its offset. The hypotheses are the frame's and the refined roll, each with
   the frame's pitch plus a coarse grid of offsets, then a fine grid around the best.
3. **Horizontal VPs along each horizon.** Every non-vertical segment's line meets the hypothesised horizon at one
   point, the horizontal direction ``l_i x u``; a weighted histogram of those directions (by their angle ``psi``
   on the horizontal great circle, length-weighted, down-weighted for segments that point at the zenith) peaks
   where many segments share a VP on that horizon (each building block's VPs). The ``num_peaks`` highest
   separated peaks are that horizon's horizontal VPs.
4. **Line support.** The score of a hypothesis is the fraction of the total segment length explained by its
   zenith or one of its horizontal VPs, ``sum_i L_i max_v k(theta_i(v)) / sum_i L_i`` with ``theta_i(v)`` the
   image angle between segment ``i`` and the ray from its midpoint to ``v`` and ``k(t) = max(0, 1 - sin^2 t /
   (4 sin^2 kernel_deg))`` (the same measure for every hypothesis, the frame's included). The refined horizon
   replaces the frame's only where its support is higher by more than ``margin`` (relative); the margin was chosen
   on renders. :func:`search_horizon` is the search without this choice and :func:`choose_horizon` the choice (the
   parser runs them apart: the confidence also reads the search's hypotheses); a logistic chooser fitted on renders
   was measured no better than the margin on the real sets (``docs/lab-notes/horizon-chooser.md``).

Consistency of the reported camera: the focal length and ``K`` stay the frame's (or, with ``focal_scales``, the
chosen hypothesis' scaled focal length); the chosen hypothesis is an up vector ``u``, so the zenith is ``K u``, the
horizon ``K^-T u`` (the polar of the zenith, so ``f^2 = -(z . h)`` holds for every horizontal VP ``h`` on it in
centred pixels), pitch and roll those of ``u``, and ``R`` is rebuilt from ``u`` and the strongest horizontal VP of
the chosen horizon (made orthogonal to ``u``, then the canonical yaw); the three VPs are ``K R``. Where the frame's
horizon is kept, the calibration is returned unchanged.
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

from ngp_kornia.geometry import (
    angles_from_rotation,
    canonical_manhattan_rotation,
    fov_from_focal,
    horizon_from_zenith,
    pitch_roll_from_up,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.models.result import Calibration

__all__ = [
    "FOCAL_SCALES",
    "Refinement",
    "choose_horizon",
    "horizon_support",
    "refine_horizon",
    "refine_up",
    "search_horizon",
    "up_from_pitch_roll",
]


def _normalize(v: Tensor) -> Tensor:
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(torch.finfo(v.dtype).tiny ** 0.5)


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


class _Cam(NamedTuple):
    """Segments in normalised camera coordinates (:func:`_cam`): midpoints (B, N, 2), directions (B, N, 2) and
    unit interpretation-plane normals (B, N, 3); the terms every hypothesis is scored with, built once: each
    segment's line through its midpoint (unit normal, :func:`_line`) and the normals as (B, 3, N) matrices, and
    the midpoint terms ``(1, m_x, m_y, |m|^2)`` (B, 4, N) of :func:`_ratio`."""

    mid: Tensor
    direction: Tensor
    normals: Tensor
    line_t: Tensor
    mid_terms: Tensor
    normals_t: Tensor

    def rows(self, index: Tensor) -> _Cam:
        """The rows ``index`` of the terms a hypothesis is scored with; the midpoints, directions and normals, which
        scoring does not read, are left out (None)."""
        return _Cam(None, None, None, self.line_t[index], self.mid_terms[index], self.normals_t[index])


def _cam(mid: Tensor, direction: Tensor, normals: Tensor) -> _Cam:
    # the (B, k, N) terms are stacked as such, not transposed after (the same values, one copy less)
    square = mid.square().sum(-1)
    terms = torch.stack([torch.ones_like(square), mid[..., 0], mid[..., 1], square], -2)
    return _Cam(mid, direction, normals, _line(mid, direction), terms, normals.transpose(-1, -2).contiguous())


def _line(mid: Tensor, direction: Tensor) -> Tensor:
    """The line through each midpoint along its direction, ``(-s_y, s_x, s_y m_x - s_x m_y) / |s|`` (B, 3, N)."""
    tiny = torch.finfo(mid.dtype).tiny ** 0.5
    sx, sy = direction[..., 0], direction[..., 1]
    line = torch.stack([-sy, sx, sy * mid[..., 0] - sx * mid[..., 1]], -2)
    return line / torch.linalg.vector_norm(direction, dim=-1).unsqueeze(-2).clamp_min(tiny)


def _camera_segments(segments: Tensor, K: Tensor) -> _Cam:
    """Segments in normalised camera coordinates ``K^-1 p`` (:class:`_Cam`). ``K^-1`` is a similarity for square
    pixels, so image angles are kept."""
    return _cam(*_camera_points(segments, K))


def _camera_points(segments: Tensor, K: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The midpoints, directions and unit plane normals of :func:`_camera_segments`."""
    ones = segments.new_ones(*segments.shape[:-1], 1)
    pts = torch.cat([segments, ones], -1)  # (B, N, 2, 3)
    cam = torch.bmm(pts.flatten(1, 2), torch.linalg.inv(K).transpose(-1, -2)).view_as(pts)
    cam = cam / cam[..., 2:]  # (x, y, 1): z / z is exactly 1
    xy = cam[..., :2]
    mid, direction = xy.mean(-2), xy[..., 1, :] - xy[..., 0, :]
    return mid, direction, _normalize(torch.linalg.cross(cam[..., 0, :], cam[..., 1, :]))


def _ratio(cam: _Cam, vps: Tensor, inplace: bool = False) -> tuple[Tensor, Tensor]:
    """Numerator ``(|s x d| / |s|)^2`` and denominator ``|d|^2`` (B, V, N) of the squared sine of :func:`_sin2`,
    with ``d = v_xy - m v_z`` the ray from each midpoint ``m`` to each VP ``v`` (B, V, 3); ``inplace`` (no
    autograd) reuses the products' memory. ``|d|^2`` is one product of per-VP terms ``(|v_xy|^2, -2 v_z v_x,
    -2 v_z v_y, v_z^2)`` with per-segment terms ``(1, m_x, m_y, |m|^2)`` (:class:`_Cam`)."""
    num = torch.bmm(vps, cam.line_t)
    num = torch.square(num, out=num if inplace else None)
    vxy, vz = vps[..., :2], vps[..., 2:]
    terms = torch.cat([vxy.square().sum(-1, keepdim=True), _numbers(vz, -2.0)[0] * vz * vxy, vz.square()], -1)
    return num, torch.bmm(terms, cam.mid_terms)


def _sin2(cam: _Cam, vps: Tensor) -> Tensor:
    """Squared sine of the image angle between every segment and the ray from its midpoint to every VP
    (normalised camera coordinates).

    Args:
        cam: the segments (:class:`_Cam`); vps: (B, ..., 3) directions (VPs at infinity allowed).

    Returns:
        (B, ..., N) in [0, 1]; a VP at the midpoint gives 1, a zero-length segment 0 (padding: mask it).
    """
    tiny = torch.finfo(vps.dtype).tiny ** 0.5
    num, den = _ratio(cam, vps.reshape(vps.shape[0], -1, 3))
    sin2 = torch.where(den > tiny, num / den.clamp_min(tiny), 1.0).clamp_max(1.0)
    return sin2.reshape(*vps.shape[:-1], -1)


def _kernel(cam: _Cam, vps: Tensor, kernel_deg: float, mask: Tensor | None, keep: Tensor | None = None) -> Tensor:
    """Closeness ``max(0, 1 - sin^2 theta / (4 sin^2 sigma))`` of every segment to the nearest of a group of VPs
    (``theta`` as in :func:`_sin2`, ``sigma`` = ``kernel_deg``): 1 on the VP, 3/4 at ``sigma``, 0 beyond
    ``2 sigma`` (a cheap stand-in for a Gaussian of width ``sigma``).

    Args:
        cam: the segments (:class:`_Cam`); vps: (B, H, P, 3), P VPs per group; mask: (B, N) bool, the segments
            that count (None: all, for a caller that weighs them by lengths 0 where masked; the closeness is finite
            and at least +0, so it then gives the same products); keep: (B, H, P) bool, the VPs that count (all
            when omitted).

    Returns:
        (B, H, N): the largest closeness over each group's kept VPs (0 where none is kept or masked).

    The values of :func:`_sin2` and the closeness taken VP by VP, with fewer full-size passes (this dominates the
    search's time): the closeness falls with ``sin^2``, so the largest is that of the smallest ``sin^2``; the
    guard against a VP on a midpoint runs only where one is that close, and without autograd the arithmetic runs
    in place."""
    B, H, P, _ = vps.shape
    tiny = torch.finfo(vps.dtype).tiny ** 0.5
    v = vps.reshape(B, H * P, 3)
    grad = torch.is_grad_enabled() and (v.requires_grad or cam.line_t.requires_grad or cam.mid_terms.requires_grad)
    num, den = _ratio(cam, v, not grad)
    if den.amin().item() > tiny:  # tiny, a power of 2, is the same number in the tensor's dtype
        sin2 = torch.div(num, den, out=None if grad else num)
    else:
        sin2 = torch.where(den > tiny, num / den.clamp_min(tiny), 1.0)
    if keep is not None and not bool(keep.all()):
        sin2 = sin2.masked_fill(~keep.reshape(B, H * P, 1), math.inf)
    sin2 = sin2.view(B, H, P, -1).amin(2) if P > 1 else sin2.view(B, H, -1)
    c = 4.0 * math.sin(math.radians(kernel_deg)) ** 2
    if c > 1.0:  # below, a clamped 1 and anything above 1 both give 0
        sin2 = sin2.clamp_max(1.0)
    if grad:
        out = (1.0 - sin2 / c).clamp_min(0.0)
        return out if mask is None else out * mask[:, None]
    c_t, one = _numbers(sin2, c, 1.0)
    out = sin2.div_(c_t).neg_().add_(one).clamp_min_(0.0)  # 1 - x as -x + 1: the same value
    return out if mask is None else out.mul_(mask[:, None])


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
    return _refine_up(up, _camera_segments(segments, K), _lengths(segments, mask), mask, zenith_tol, iterations)


def _scaled_focal(K: Tensor, scale: Tensor) -> Tensor:
    """``K`` (B, 3, 3) with its focal length times ``scale`` (B,, K's dtype), the principal point kept."""
    key = ("focal entries", K.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            entries = [[1, 0, 0], [0, 1, 0], [0, 0, 0]]
            _CONSTANTS[key] = (torch.tensor(entries, dtype=torch.bool, device=K.device),)
    return torch.where(_CONSTANTS[key][0], K * scale[:, None, None], K)


def _lengths(segments: Tensor, mask: Tensor) -> Tensor:
    return torch.linalg.vector_norm(segments[..., 1, :] - segments[..., 0, :], dim=-1) * mask.to(segments)


def _refine_up(
    up: Tensor, cam: _Cam, lengths: Tensor, mask: Tensor, zenith_tol: float, iterations: int
) -> tuple[Tensor, Tensor]:
    """:func:`refine_up` on segments already in camera coordinates."""
    cos_tol = math.cos(math.radians(10.0))
    cur, ok = up, None
    for _ in range(iterations):
        inlier = _near_zenith(cam, cur, math.sin(math.radians(zenith_tol)) ** 2) & mask
        w = lengths * inlier
        M = torch.bmm(w[:, None] * cam.normals_t, cam.normals)  # sum_i w_i n_i n_i^T
        _, vecs = torch.linalg.eigh(M)
        fit = vecs[..., 0].detach()  # no gradient through eigh (unstable for close eigenvalues)
        dot = (fit * up).sum(-1, keepdim=True)
        fit = torch.where(dot < 0, -fit, fit)
        good = (inlier.sum(-1) >= 3) & (dot.abs()[:, 0] > cos_tol) & torch.isfinite(fit).all(-1)  # |dot|: fit . up
        cur = torch.where(good[:, None], fit, cur)
        ok = good if ok is None else ok | good
    return _normalize(cur), torch.zeros(len(up), dtype=torch.bool, device=up.device) if ok is None else ok


def _near_zenith(cam: _Cam, up: Tensor, bound: float) -> Tensor:
    """``_sin2(cam, up[:, None])[:, 0] <= bound`` (B, N) in fewer passes for ``bound`` below 1/2: where ``|d|^2 >
    tiny`` the squared sine is ``num / den`` (the clamp of ``den`` to tiny does nothing there; the clamp of the sine
    to 1 does nothing below ``bound``), elsewhere 1, never below."""
    if bound >= 0.5:
        return _sin2(cam, up[:, None])[:, 0] <= bound
    with torch.no_grad():  # a bool: in place
        num, den = _ratio(cam, up[:, None], True)
        bound_t, tiny = _numbers(den, bound, torch.finfo(den.dtype).tiny ** 0.5)
        return (torch.div(num, den, out=num)[:, 0] <= bound_t) & (den[:, 0] > tiny)


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
    lengths = _lengths(segments, mask)
    return _support(
        ups,
        _camera_segments(segments, K),
        lengths,
        _total(lengths),
        num_peaks,
        kernel_deg,
        bins,
        separation_deg,
        zenith_ups,
    )


def _support(
    ups: Tensor,
    cam: _Cam,
    lengths: Tensor,
    total: Tensor,
    num_peaks: int,
    kernel_deg: float,
    bins: int,
    separation_deg: float,
    zenith_ups: Tensor | None,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`horizon_support` on segments already in camera coordinates (:func:`_camera_segments`), their lengths
    (B, N) 0 where masked (so the closeness needs no mask) and ``total`` (B, 1) their sum (:func:`_total`)."""
    B, H, _ = ups.shape
    kz = _kernel(cam, (ups if zenith_ups is None else zenith_ups)[:, :, None], kernel_deg, None)  # (B, H, N)
    e1, e2 = _horizontal_basis(ups)
    index, meets = _directions(ups, e1, e2, cam.normals_t, bins)
    zero, one = _numbers(kz, 0.0, 1.0)
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
    kh = _kernel(cam, dirs, kernel_deg, None, value > zero)  # (B, H, N)
    explained = torch.maximum(kz, kh)
    support = (explained * lengths[:, None]).sum(-1) / total
    return support, dirs, value


def _total(lengths: Tensor) -> Tensor:
    """The total segment length (B, 1), at least tiny^0.5 (the support's denominator)."""
    return lengths.sum(-1, keepdim=True).clamp_min(torch.finfo(lengths.dtype).tiny ** 0.5)


def _directions(ups: Tensor, e1: Tensor, e2: Tensor, nt: Tensor, bins: int) -> tuple[Tensor, Tensor]:
    """The histogram bin (B, H, N) of every segment's horizontal direction on each horizon and whether its line
    meets the horizon (B, H, N) bool."""
    # each segment's line meets the horizon in the horizontal direction n x u; with (e1, e2, u) right-handed its
    # coordinates are (n . e2, -n . e1), and |n x u|^2 = 1 - (n . u)^2
    pi, count, bound = _numbers(ups, math.pi, bins, _meets_bound(ups.dtype))
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
    bins, (three, nine) = hist.shape[-1], _numbers(hist, 3.0, 9.0)
    wrap = _wrap(hist, 2)  # wrap[..., 2 + i - k] is hist rolled by k
    near = wrap[..., 1 : bins + 1] + wrap[..., 3 : bins + 3]
    # 3 h + 2 near as one add with alpha 2: doubling is exact, so a fused multiply-add rounds the same
    return torch.add(hist.mul_(three), near, alpha=2.0).add_(wrap[..., :bins]).add_(wrap[..., 4:]).div_(nine)


def _bin_angles(bins: int, like: Tensor) -> Tensor:
    """The cosine and sine (bins, 2) of every bin's centre angle ``(i + 1/2) pi / bins``, built once per dtype and
    device (the values the same arithmetic gives element by element)."""
    key = ("bins", bins, like.dtype, like.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            angle = (torch.arange(bins, device=like.device).to(like) + 0.5) * (math.pi / bins)
            _CONSTANTS[key] = (torch.stack([torch.cos(angle), torch.sin(angle)], -1),)
    return _CONSTANTS[key][0]


def _wrap(x: Tensor, k: int) -> Tensor:
    """``x`` circularly padded by ``k`` on both sides of its last dimension (``k`` at most its length)."""
    return torch.cat([x[..., -k:], x, x[..., :k]], -1)


#: constants built once per key, dtype and device; built as ordinary tensors even inside the search's inference
#: mode (inference tensors could not serve callers with autograd)
_CONSTANTS: dict[tuple, tuple[Tensor, ...]] = {}


def _constants(key: tuple, like: Tensor, *rows: list) -> tuple[Tensor, ...]:
    """Per-call constant vectors, built once per ``key``, dtype and device (building them costs more than the
    arithmetic that uses them)."""
    key = (*key, like.dtype, like.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            _CONSTANTS[key] = tuple(torch.tensor(r, dtype=like.dtype, device=like.device) for r in rows)
    return _CONSTANTS[key]


def _numbers(like: Tensor, *values: float) -> tuple[Tensor, ...]:
    """The numbers as 0-dim tensors of ``like``'s dtype and device, built once: an operation given a Python number
    converts it to such a tensor (the same value) on every call, which costs more than the arithmetic on small
    tensors."""
    key = ("numbers", *values, like.dtype, like.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            _CONSTANTS[key] = tuple(torch.tensor(v, dtype=like.dtype, device=like.device) for v in values)
    return _CONSTANTS[key]


def _horizontal_basis(ups: Tensor) -> tuple[Tensor, Tensor]:
    """A basis ``e1, e2`` (B, H, 3) of each horizontal plane, ``(e1, e2, u)`` right-handed: ``e1`` along
    ``u x z`` (``u x x`` where ``u`` is the optical axis)."""
    ref, alt = _constants(("axes",), ups, [[[0.0, 0.0, 1.0]]], [[[1.0, 0.0, 0.0]]])  # (1, 1, 3): broadcast
    e1 = torch.linalg.cross(ups, ref)
    norm = torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    if not bool((norm > _numbers(norm, 1e-6)[0]).all()):
        e1 = torch.where(norm > 1e-6, e1, torch.linalg.cross(ups, alt))
        norm = torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    e1 = e1 / norm.clamp_min(torch.finfo(e1.dtype).tiny ** 0.5)  # _normalize
    return e1, torch.linalg.cross(ups, e1)


#: the frame's focal length is also tried times each of these (chosen on York Urban, ECD and renders together)
FOCAL_SCALES = (0.8, 0.9, 1.1, 1.25)


def refine_horizon(
    cal: Calibration,
    segments: Tensor,
    mask: Tensor,
    pitch_range: float = 8.0,
    pitch_step: float = 1.0,
    fine_step: float = 0.25,
    num_peaks: int = 4,
    kernel_deg: float = 1.0,
    zenith_tol: float = 2.0,
    margin: float = 0.08,
    tie_zenith: bool = True,
    focal_scales: tuple[float, ...] = FOCAL_SCALES,
    frame_roll: bool = False,
) -> Calibration:
    """The calibration with the horizon that the segments support best (module docstring: method, consistency).

    Args:
        cal: a batched :class:`Calibration` from the frame search.
        segments: (B, N, 2, 2) segments in the same pixels; mask: (B, N) bool.
        pitch_range: the coarse hypotheses span the frame's pitch +- this, degrees.
        pitch_step: coarse step, degrees.
        fine_step: step of the fine grid around the best coarse hypothesis, degrees.
        num_peaks: horizontal VPs per horizon.
        kernel_deg: width of the closeness kernel, degrees.
        zenith_tol: inlier angle of the zenith refinement, degrees.
        margin: the refined horizon must beat the frame's support by this fraction.
        tie_zenith: score each hypothesis' vertical segments against its own zenith ``K u``, so pitch moves the
            zenith and the horizon together and the verticals' convergence weighs in; False scores them against the
            frame's or the refined zenith, whichever gave the hypothesis its roll, so the horizontal VPs alone place
            the horizon (measured worse on every set: the horizontal VPs of clutter then go unchecked).
        focal_scales: the hypotheses are repeated with the frame's focal length times each of these (1 is always
            included and first); where another scale wins, ``K``, focal and FoV follow it.
        frame_roll: search the pitch grid with the frame's roll as well as with the refined zenith's (twice the
            hypotheses and about 1.5x the time); by default only the frame's own hypothesis keeps the frame's roll.

    Returns:
        a :class:`Calibration` of the same shapes: unchanged where the frame's horizon is kept or the frame was
        invalid; otherwise ``R``, ``up``, ``zenith``, ``horizon``, ``vps``, ``pitch``, ``roll``, ``yaw`` follow
        the refined up vector, and ``K``, focal and FoV the chosen focal scale.
    """
    found = search_horizon(
        cal,
        segments,
        mask,
        pitch_range,
        pitch_step,
        fine_step,
        num_peaks,
        kernel_deg,
        zenith_tol,
        tie_zenith,
        focal_scales,
        frame_roll,
    )
    return choose_horizon(cal, found, margin)


def choose_horizon(cal: Calibration, found: Refinement, margin: float = 0.08) -> Calibration:
    """The choice of :func:`refine_horizon`: the calibration ``cal`` with the horizon that :func:`search_horizon`
    found on it, where that horizon's line support beats the frame's by more than ``margin`` (relative); else
    ``cal`` as it is."""
    better = found.support > found.frame_support * (1.0 + margin)
    use = cal.valid & better & torch.isfinite(found.up).all(-1)
    return _with_up(cal, use, torch.where(use[:, None, None], found.K, cal.K), found.up, found.horizontal)


class Refinement(NamedTuple):
    """What the horizon search found, per image (:func:`search_horizon`).

    Attributes:
        up: (B, 3) the best hypothesis' up vector.
        horizontal: (B, 3) its strongest horizontal VP direction (camera coordinates).
        K: (B, 3, 3) the frame's ``K`` at the best hypothesis' focal scale.
        support: (B,) its line support.
        frame_support: (B,) the line support of the frame's own horizon.
        peaks: (B, P) histogram weights of the best hypothesis' horizontal VPs over the total segment length.
        frame_peaks: (B, P) the same for the frame's own horizon.
        up_refined: (B, 3) the least-squares up vector of the zenith refinement (the hypotheses' roll).
        scale: (B,) the best hypothesis' focal scale.
        hypothesis_support: (B, S * H) the line support of every coarse hypothesis (S focal scales, scale-major,
            H pitches; column 0 is the frame's own horizon).
        hypothesis_horizon: (B, S * H, 3) their horizons, lines in the image's pixels (``K_s^-T u``).
    """

    up: Tensor
    horizontal: Tensor
    K: Tensor
    support: Tensor
    frame_support: Tensor
    peaks: Tensor
    frame_peaks: Tensor
    up_refined: Tensor
    scale: Tensor
    hypothesis_support: Tensor
    hypothesis_horizon: Tensor


def search_horizon(
    cal: Calibration,
    segments: Tensor,
    mask: Tensor,
    pitch_range: float = 8.0,
    pitch_step: float = 1.0,
    fine_step: float = 0.25,
    num_peaks: int = 4,
    kernel_deg: float = 1.0,
    zenith_tol: float = 2.0,
    tie_zenith: bool = True,
    focal_scales: tuple[float, ...] = FOCAL_SCALES,
    frame_roll: bool = False,
) -> Refinement:
    """The search of :func:`refine_horizon` (same arguments) without the choice: the best hypothesis and what is
    known about it and about the frame's own horizon."""
    args = (cal, segments, mask, pitch_range, pitch_step, fine_step, num_peaks, kernel_deg, zenith_tol, tie_zenith)
    if torch.is_grad_enabled():
        return _search_horizon(*args, focal_scales, frame_roll)
    # without autograd, inference mode spares every operation its autograd bookkeeping (about a tenth of the
    # search's time, the same arithmetic); the answers are cloned out of it as ordinary tensors
    with torch.inference_mode():
        found = _search_horizon(*args, focal_scales, frame_roll)
    return Refinement(*(t.clone() for t in found))


def _search_horizon(
    cal, segments, mask, pitch_range, pitch_step, fine_step, num_peaks, kernel_deg, zenith_tol, tie_zenith,
    focal_scales, frame_roll,
) -> Refinement:
    seg = segments.to(cal.K.dtype)
    scales = [1.0] + [float(x) for x in focal_scales if float(x) != 1.0]  # the frame's focal length first
    (cam, cam_s), lengths = _search_cams(seg, cal.K, scales), _lengths(seg, mask)
    grid = _pitch_grid(cal.up, cam, lengths, mask, pitch_range, pitch_step, zenith_tol, frame_roll)
    search = _Search(num_peaks, kernel_deg, tie_zenith)
    coarse = _coarse_search(cal.K, cam, lengths, mask, grid, scales, search, cam_s)
    total = _total(lengths)
    up, horizontal, support, peaks = _fine_search(cam, lengths, total, grid, coarse, pitch_step, fine_step, search)
    scale_values = _scale_constants(scales, cal.K)[0]
    return Refinement(
        up,
        horizontal,
        coarse.K,
        support,
        coarse.support[:, 0],
        peaks / total,
        coarse.peaks[:, 0] / total,
        grid.up_refined,
        coarse.scale,
        coarse.support,
        _hypothesis_horizons(cal.K, grid.ups, scale_values),
    )


def _hypothesis_horizons(K: Tensor, ups: Tensor, scales: Tensor) -> Tensor:
    """Pixel horizons ``K_s^-T u`` (B, S * H, 3), scale-major, of the (B, H, 3) up vectors with ``K``'s focal
    length times each of the (S,) scales: ``(u_x / f, u_y / f, u_z - (c_x u_x + c_y u_y) / f)``."""
    f = K[:, None, None, 0, 0] * scales[None, :, None]  # (B, S, 1)
    cx, cy = K[:, None, None, 0, 2], K[:, None, None, 1, 2]
    ux, uy, uz = ups[:, None].unbind(-1)  # (B, 1, H) each
    lines = torch.stack([ux / f, uy / f, uz - (cx * ux + cy * uy) / f], -1)  # (B, S, H, 3)
    return lines.flatten(1, 2)


class _Search(NamedTuple):
    num_peaks: int
    kernel_deg: float
    tie_zenith: bool


class _Grid(NamedTuple):
    pitches: Tensor  # (B, H) degrees
    rolls: Tensor  # (B, H) degrees
    zen: Tensor  # (B, H, 3) the zenith each hypothesis took its roll from
    ups: Tensor  # (B, H, 3)
    up_refined: Tensor  # (B, 3) the least-squares up vector


class _Coarse(NamedTuple):
    support: Tensor  # (B, S * H), scale-major; column 0 is the frame's own hypothesis
    dirs: Tensor  # (B, S * H, P, 3) horizontal VP directions
    cam: _Cam  # the camera-coordinate segments of every scale, scale-major rows
    best: Tensor  # (B,) index into the S * H hypotheses
    K: Tensor  # (B, 3, 3) K with the best hypothesis' focal scale
    peaks: Tensor  # (B, S * H, P) histogram weights of the horizontal VPs
    scale: Tensor  # (B,) the best hypothesis' focal scale


def _pitch_grid(up_frame, cam, lengths, mask, pitch_range, pitch_step, zenith_tol, frame_roll) -> _Grid:
    """The coarse hypotheses: the frame's own first, then the refined zenith's roll with every pitch offset."""
    up_ref, _ = _refine_up(up_frame, cam, lengths, mask, zenith_tol, 2)
    pitch, roll = pitch_roll_from_up(torch.stack([up_frame, up_ref]))
    pitch0, roll0, roll1 = pitch[0], roll[0], roll[1]
    n = int(round(pitch_range / pitch_step))
    offsets = _pitch_offsets(n, pitch_step, up_frame)
    if frame_roll:  # the frame's and the refined roll, each with every pitch
        pitches = (pitch0[:, None] + offsets).repeat(1, 2)
        rolls = torch.cat([roll0[:, None].expand(-1, len(offsets)), roll1[:, None].expand(-1, len(offsets))], 1)
        zen = torch.cat([up_frame[:, None].expand(-1, len(offsets), 3), up_ref[:, None].expand(-1, len(offsets), 3)], 1)
    else:  # the frame's hypothesis, then the refined roll with every pitch
        pitches = torch.cat([pitch0[:, None], pitch0[:, None] + offsets], 1)
        rolls = torch.cat([roll0[:, None], roll1[:, None].expand(-1, len(offsets))], 1)
        zen = torch.cat([up_frame[:, None], up_ref[:, None].expand(-1, len(offsets), 3)], 1)
    return _Grid(pitches, rolls, zen, up_from_pitch_roll(pitches, rolls), up_ref)


def _pitch_offsets(n: int, step: float, like: Tensor) -> Tensor:
    """``step`` times 0, then -n..n without 0 (the frame's pitch first), as :func:`torch.arange` would give them."""
    key = ("pitch", n, step, like.dtype, like.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            offsets = torch.arange(-n, n + 1, dtype=like.dtype, device=like.device) * step
            _CONSTANTS[key] = (torch.cat([offsets.new_zeros(1), offsets[offsets != 0]]),)
    return _CONSTANTS[key][0]


def _coarse_search(K, cam, lengths, mask, grid: _Grid, scales: list[float], search: _Search, cam_s=None) -> _Coarse:
    """Support of every hypothesis at every focal scale, in one pass (each scale its own batch rows); ``cam_s``: the
    segments at every scale (:func:`_search_cams`), built here when omitted."""
    S, B, Hn = len(scales), len(K), grid.ups.shape[1]
    scale, inv, stretch = _scale_constants(scales, K)
    cam_s = _scaled_cam(cam, inv, stretch) if cam_s is None else cam_s
    lengths_s = lengths.repeat(S, 1)
    sup, d, v = _support(
        grid.ups.repeat(S, 1, 1),
        cam_s,
        lengths_s,
        _total(lengths_s),
        search.num_peaks,
        search.kernel_deg,
        360,
        3.0,
        None if search.tie_zenith else grid.zen.repeat(S, 1, 1),
    )
    support = sup.view(S, B, Hn).transpose(0, 1).reshape(B, S * Hn)
    dirs = d.view(S, B, Hn, -1, 3).transpose(0, 1).reshape(B, S * Hn, -1, 3)
    peaks = v.view(S, B, Hn, -1).transpose(0, 1).reshape(B, S * Hn, -1)
    best = support.argmax(-1)
    best_scale = scale[best // Hn]
    return _Coarse(support, dirs, cam if S == 1 else cam_s, best, _scaled_focal(K, best_scale), peaks, best_scale)


def _scaled_cam(cam: _Cam, inv: Tensor, stretch: Tensor) -> _Cam:
    """The segments seen with the focal length times each of S scales (:func:`_scale_constants`), (S * B) rows,
    scale-major. ``K^-1`` with ``f`` times ``x`` maps the centred points to ``p / x``: midpoints and directions scale
    by ``1 / x``, and the plane normal ``(n_x, n_y, n_z)`` becomes ``(x n_x, x n_y, n_z)`` up to its length."""
    return _scaled(cam.mid, cam.direction, cam.normals, inv, stretch)


def _scaled(mid: Tensor, direction: Tensor, normals: Tensor, inv: Tensor, stretch: Tensor) -> _Cam:
    mid_s, direction_s = (mid * inv).flatten(0, 1), (direction * inv).flatten(0, 1)
    return _cam(mid_s, direction_s, _normalize((normals * stretch).flatten(0, 1)))


def _search_cams(segments: Tensor, K: Tensor, scales: list[float]) -> tuple[_Cam, _Cam]:
    """The segments in camera coordinates (:func:`_camera_segments`) and at every focal scale (:func:`_scaled_cam`),
    the first scale 1. Its rows' line and midpoint terms are the unscaled segments' (times 1 is exact), so those are
    built once; its normals are normalised again, so the unscaled ones are kept apart."""
    mid, direction, normals = _camera_points(segments, K)
    _, inv, stretch = _scale_constants(scales, K)
    scaled = _scaled(mid, direction, normals, inv, stretch)
    B = len(K)
    cam = _Cam(mid, direction, normals, scaled.line_t[:B], scaled.mid_terms[:B], normals.transpose(-1, -2).contiguous())
    return cam, scaled


def _scale_constants(scales: list[float], like: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The focal scales (S,), their inverses (S, 1, 1, 1) and the stretch of the plane normals (S, 1, 1, 3)."""
    key = ("scales", *scales, like.dtype, like.device)
    if key not in _CONSTANTS:
        with torch.inference_mode(False):  # ordinary tensors (see _CONSTANTS)
            inv = torch.tensor([1.0 / x for x in scales]).to(like)[:, None, None, None]
            stretch = torch.cat([1.0 / inv, 1.0 / inv, torch.ones_like(inv)], -1)
            _CONSTANTS[key] = (torch.tensor(scales, dtype=like.dtype, device=like.device), inv, stretch)
    return _CONSTANTS[key]


def _fine_search(cam, lengths, total, grid: _Grid, coarse: _Coarse, pitch_step, fine_step, search: _Search):
    """Pitches ``fine_step`` apart around the best coarse hypothesis, at its roll and focal scale: the chosen up
    vectors (B, 3), their strongest horizontal VP directions (B, 3), their support (B,) and their horizontal VPs'
    histogram weights (B, P); ``total`` (B, 1) is :func:`_total` of the lengths."""
    B, Hn = len(coarse.best), grid.ups.shape[1]
    rows = torch.arange(B, device=coarse.best.device)
    hyp, best = coarse.best % Hn, coarse.best
    m = max(1, int(round(pitch_step / fine_step)))
    fine = _pitch_offsets(m - 1, fine_step, grid.ups)[1:]
    # the best coarse hypothesis first: its up vector is the grid's (the same arithmetic on the same angles)
    cand_up = grid.ups[rows, hyp][:, None]
    cand_support, cand_dirs = coarse.support[rows, best][:, None], coarse.dirs[rows, best][:, None]
    cand_peaks = coarse.peaks[rows, best][:, None]
    if len(fine):
        pitch, roll = grid.pitches[rows, hyp][:, None], grid.rolls[rows, hyp][:, None]
        fine_p = pitch + fine
        fine_up = up_from_pitch_roll(fine_p, roll.expand_as(fine_p))
        fine_zen = None if search.tie_zenith else grid.zen[rows, hyp][:, None].expand(-1, len(fine), 3)
        cam_best = coarse.cam if len(coarse.cam[0]) == B else coarse.cam.rows((best // Hn) * B + rows)
        fine_support, fine_dirs, fine_peaks = _support(
            fine_up, cam_best, lengths, total, search.num_peaks, search.kernel_deg, 360, 3.0, fine_zen
        )
        cand_up = torch.cat([cand_up, fine_up], 1)
        cand_support = torch.cat([cand_support, fine_support], 1)
        cand_dirs = torch.cat([cand_dirs, fine_dirs], 1)
        cand_peaks = torch.cat([cand_peaks, fine_peaks], 1)
    pick = cand_support.argmax(-1)
    return cand_up[rows, pick], cand_dirs[rows, pick, 0], cand_support[rows, pick], cand_peaks[rows, pick]


def _with_up(cal: Calibration, use: Tensor, K: Tensor, up: Tensor, horizontal: Tensor) -> Calibration:
    """The calibration with, where ``use``, the up vector ``up``, the rotation from it and the horizontal VP
    direction, and ``K``; every other field follows, so the horizon is the polar of the zenith."""
    if not bool(use.any()):  # every frame kept (the common case): the fields the choice below would give
        return replace(cal, K=K, focal=K[:, 0, 0], up=-cal.R[..., :, 1])
    down = -up
    h = _normalize(horizontal - (horizontal * up).sum(-1, keepdim=True) * up)
    R = canonical_manhattan_rotation(torch.stack([h, down, torch.linalg.cross(h, down)], -1))
    R = torch.where(use[:, None, None], R, cal.R)
    up = -R[..., :, 1]
    zenith = _normalize(zenith_from_up(K, up))
    pitch, roll = pitch_roll_from_up(up)
    _, _, yaw = angles_from_rotation(R)
    focal = K[:, 0, 0]
    height, width = cal.image_size[:, 0].to(K), cal.image_size[:, 1].to(K)
    return replace(
        cal,
        K=K,
        focal=focal,
        fov_v=torch.where(use, fov_from_focal(focal, height), cal.fov_v),
        fov_h=torch.where(use, fov_from_focal(focal, width), cal.fov_h),
        R=R,
        up=up,
        zenith=torch.where(use[:, None], zenith, cal.zenith),
        horizon=torch.where(use[:, None], horizon_from_zenith(K, zenith), cal.horizon),
        vps=torch.where(use[:, None, None], vanishing_points_from_rotation(K, R), cal.vps),
        pitch=torch.where(use, pitch, cal.pitch),
        roll=torch.where(use, roll, cal.roll),
        yaw=torch.where(use, yaw, cal.yaw),
    )
