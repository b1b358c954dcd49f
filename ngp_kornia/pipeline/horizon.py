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

from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import torch
from torch import Tensor

from ngp_kornia.geometry import (
    canonical_manhattan_rotation,
    pitch_roll_from_up,
    rotation_from_up,
    segment_lengths,
)
from ngp_kornia.pipeline.constants import cached
from ngp_kornia.pipeline.horizon_support import refine_up_on_camera, support_on_camera, up_from_pitch_roll
from ngp_kornia.pipeline.line_kernel import (
    CameraSegments,
    camera_segments_at_scales,
    scale_constants,
    scaled_camera_segments,
    scaled_focal,
    total_length,
)
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.settings import HorizonSettings

__all__ = ["Refinement", "choose_horizon", "refine_horizon", "search_horizon"]


def refine_horizon(
    cal: Calibration,
    segments: Tensor,
    mask: Tensor,
    settings: HorizonSettings | None = None,
    known_focal: bool = False,
) -> Calibration:
    """The calibration with the horizon that the segments support best (module docstring: method, consistency):
    :func:`search_horizon`, then :func:`choose_horizon`.

    Args:
        cal: a batched :class:`Calibration` from the frame search.
        segments: (B, N, 2, 2) segments in the same pixels; mask: (B, N) bool.
        settings: the search's settings (:class:`~ngp_kornia.pipeline.settings.HorizonSettings`); None for the
            defaults.
        known_focal: the focal length is known: only the horizon moves (no focal scales).

    Returns:
        a :class:`Calibration` of the same shapes: unchanged where the frame's horizon is kept or the frame was
        invalid; otherwise ``R``, ``up``, ``zenith``, ``horizon``, ``vps``, ``pitch``, ``roll``, ``yaw`` follow
        the refined up vector, and ``K``, focal and FoV the chosen focal scale.
    """
    settings = settings or HorizonSettings()
    return choose_horizon(cal, search_horizon(cal, segments, mask, settings, known_focal), settings.margin)


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
    settings: HorizonSettings | None = None,
    known_focal: bool = False,
    keep_ups: Callable[[Tensor], Tensor] | None = None,
    weights: Tensor | None = None,
) -> Refinement:
    """The search of :func:`refine_horizon` (same arguments) without the choice: the best hypothesis and what is
    known about it and about the frame's own horizon. ``keep_ups`` maps (B, H, 3) up vectors to (B, H) bool, the
    hypotheses allowed (a gravity prior's range, :func:`~ngp_kornia.pipeline.gravity.allowed_ups`); the frame's own
    is always allowed. ``weights`` (B, N), when given, multiply the segments' lengths in the line support (the line
    evidence's structure weights)."""
    settings = settings or HorizonSettings()
    if torch.is_grad_enabled():
        return _search_horizon(cal, segments, mask, settings, known_focal, keep_ups, weights)
    # without autograd, inference mode spares every operation its autograd bookkeeping (about a tenth of the
    # search's time, the same arithmetic); the answers are cloned out of it as ordinary tensors
    with torch.inference_mode():
        found = _search_horizon(cal, segments, mask, settings, known_focal, keep_ups, weights)
    return Refinement(*(t.clone() for t in found))


def _search_horizon(
    cal: Calibration,
    segments: Tensor,
    mask: Tensor,
    settings: HorizonSettings,
    known_focal: bool,
    keep_ups=None,
    weights: Tensor | None = None,
) -> Refinement:
    seg = segments.to(cal.K.dtype)
    # the frame's focal length first; with a known focal length only that one
    scales = [1.0] + ([] if known_focal else [x for x in settings.focal_scales if x != 1.0])
    (cam, cam_s), lengths = camera_segments_at_scales(seg, cal.K, scales), segment_lengths(seg, mask)
    if weights is not None:
        lengths = lengths * weights.to(lengths)
    s = settings
    grid = _pitch_grid(cal.up, cam, lengths, mask, s.pitch_range, s.pitch_step, s.zenith_tol, s.frame_roll)
    search = _Search(s.num_peaks, s.kernel_deg, s.tie_zenith, keep_ups)
    coarse = _coarse_search(cal.K, cam, lengths, mask, grid, scales, search, cam_s)
    total = total_length(lengths)
    up, horizontal, support, peaks = _fine_search(cam, lengths, total, grid, coarse, s.pitch_step, s.fine_step, search)
    scale_values = scale_constants(scales, cal.K)[0]
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
    keep_ups: Callable[[Tensor], Tensor] | None = None


def _kept(support: Tensor, ups: Tensor, search: _Search, first: bool) -> Tensor:
    """The (B, ..., H) supports with the hypotheses (up vectors (B, ..., H, 3), broadcast) that ``search.keep_ups``
    refuses set to -1 (never chosen); with ``first``, the first (the frame's own hypothesis) is always kept."""
    if search.keep_ups is None:
        return support
    keep = search.keep_ups(ups)
    if first:
        keep[..., 0] = True
    return torch.where(keep, support, torch.full_like(support, -1.0))


class _Grid(NamedTuple):
    pitches: Tensor  # (B, H) degrees
    rolls: Tensor  # (B, H) degrees
    zen: Tensor  # (B, H, 3) the zenith each hypothesis took its roll from
    ups: Tensor  # (B, H, 3)
    up_refined: Tensor  # (B, 3) the least-squares up vector


class _Coarse(NamedTuple):
    support: Tensor  # (B, S * H), scale-major; column 0 is the frame's own hypothesis
    dirs: Tensor  # (B, S * H, P, 3) horizontal VP directions
    cam: CameraSegments  # the camera-coordinate segments of every scale, scale-major rows
    best: Tensor  # (B,) index into the S * H hypotheses
    K: Tensor  # (B, 3, 3) K with the best hypothesis' focal scale
    peaks: Tensor  # (B, S * H, P) histogram weights of the horizontal VPs
    scale: Tensor  # (B,) the best hypothesis' focal scale


def _pitch_grid(up_frame, cam, lengths, mask, pitch_range, pitch_step, zenith_tol, frame_roll) -> _Grid:
    """The coarse hypotheses: the frame's own first, then the refined zenith's roll with every pitch offset."""
    up_ref, _ = refine_up_on_camera(up_frame, cam, lengths, mask, zenith_tol, 2)
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

    def build() -> Tensor:
        offsets = torch.arange(-n, n + 1, dtype=like.dtype, device=like.device) * step
        return torch.cat([offsets.new_zeros(1), offsets[offsets != 0]])

    return cached(("pitch", n, step, like.dtype, like.device), build)


def _coarse_search(K, cam, lengths, mask, grid: _Grid, scales: list[float], search: _Search, cam_s=None) -> _Coarse:
    """Support of every hypothesis at every focal scale, in one pass (each scale its own batch rows); ``cam_s``: the
    segments at every scale (:func:`camera_segments_at_scales`), built here when omitted."""
    S, B, Hn = len(scales), len(K), grid.ups.shape[1]
    scale, inv, stretch = scale_constants(scales, K)
    cam_s = scaled_camera_segments(cam, inv, stretch) if cam_s is None else cam_s
    lengths_s = lengths.repeat(S, 1)
    sup, d, v = support_on_camera(
        grid.ups.repeat(S, 1, 1),
        cam_s,
        lengths_s,
        total_length(lengths_s),
        search.num_peaks,
        search.kernel_deg,
        360,
        3.0,
        None if search.tie_zenith else grid.zen.repeat(S, 1, 1),
    )
    support = sup.view(S, B, Hn).transpose(0, 1).reshape(B, S * Hn)
    if search.keep_ups is not None:  # the same up vectors at every scale, scale-major
        support = _kept(support.view(B, S, Hn), grid.ups[:, None], search, True).view(B, S * Hn)
    dirs = d.view(S, B, Hn, -1, 3).transpose(0, 1).reshape(B, S * Hn, -1, 3)
    peaks = v.view(S, B, Hn, -1).transpose(0, 1).reshape(B, S * Hn, -1)
    best = support.argmax(-1)
    best_scale = scale[best // Hn]
    return _Coarse(support, dirs, cam if S == 1 else cam_s, best, scaled_focal(K, best_scale), peaks, best_scale)


def _fine_search(cam, lengths, total, grid: _Grid, coarse: _Coarse, pitch_step, fine_step, search: _Search):
    """Pitches ``fine_step`` apart around the best coarse hypothesis, at its roll and focal scale: the chosen up
    vectors (B, 3), their strongest horizontal VP directions (B, 3), their support (B,) and their horizontal VPs'
    histogram weights (B, P); ``total`` (B, 1) is :func:`total_length` of the lengths."""
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
        fine_support, fine_dirs, fine_peaks = support_on_camera(
            fine_up, cam_best, lengths, total, search.num_peaks, search.kernel_deg, 360, 3.0, fine_zen
        )
        cand_up = torch.cat([cand_up, fine_up], 1)
        cand_support = torch.cat([cand_support, _kept(fine_support, fine_up, search, False)], 1)
        cand_dirs = torch.cat([cand_dirs, fine_dirs], 1)
        cand_peaks = torch.cat([cand_peaks, fine_peaks], 1)
    pick = cand_support.argmax(-1)
    return cand_up[rows, pick], cand_dirs[rows, pick, 0], cand_support[rows, pick], cand_peaks[rows, pick]


def _with_up(cal: Calibration, use: Tensor, K: Tensor, up: Tensor, horizontal: Tensor) -> Calibration:
    """The calibration with, where ``use``, the up vector ``up``, the rotation from it and the horizontal VP
    direction, and ``K``; every other field follows (the camera's), so the horizon is the polar of the zenith."""
    if not bool(use.any()):  # every frame kept (the common case): K is the calibration's own
        return cal
    R = torch.where(use[:, None, None], canonical_manhattan_rotation(rotation_from_up(up, horizontal)), cal.R)
    return replace(cal, camera=cal.camera.with_matrix(K, R))
