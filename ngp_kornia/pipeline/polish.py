"""Polishing the frame search's Manhattan frame on its inlier segments: rotation by Gauss-Newton and focal length
by a search over scales, each scored by line support.

The frame search samples VPs from pairs of segments and averages the best frames (Eq. 23); no step fits the
frame to all the segments that point at its VPs. Here, for each focal scale ``s`` of :attr:`PolishSettings.scales`
(times the frame's focal length), the rotation is refitted: segments within ``inlier_deg`` (image angle between the
segment and the ray from its midpoint to the VP) of one of the frame's three VPs are that VP's inliers, and a
Gauss-Newton step on a small rotation ``w`` minimises ``sum_i L_i (n_i . (d_j + w x d_j))^2`` (``n_i`` the unit
normal of segment ``i``'s interpretation plane, ``d_j`` the VP direction, ``L_i`` the length), repeated
``iterations`` times with the inliers chosen again. Each scale's frame is scored by the line support of its three
VPs (the fraction of segment length explained, the closeness kernel of :mod:`ngp_kornia.pipeline.line_kernel`); a scale
other than 1 is taken only where its support beats scale 1's by ``focal_margin``, and the chosen frame replaces
the search's where its support is higher than the search's frame. The settings were chosen on the real development
sets and renders together (BENCHMARKS.md).
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from torch import Tensor

from ngp_kornia.geometry import canonical_manhattan_rotation, segment_lengths
from ngp_kornia.pipeline.line_kernel import (
    camera_segments,
    closeness_kernel,
    scaled_camera_segments,
    scaled_focal,
    squared_sines,
)
from ngp_kornia.pipeline.settings import PolishSettings

__all__ = ["polish_frame", "refit_rotation"]


def refit_rotation(cam, lengths: Tensor, mask: Tensor, R: Tensor, inlier_deg: float, iterations: int) -> Tensor:
    """Rotations (M, 3, 3) refitted on their VPs' inlier segments by Gauss-Newton (the module docstring's step).

    Args:
        cam: (M, N) segments in camera coordinates (:class:`~ngp_kornia.pipeline.line_kernel.CameraSegments`).
        lengths: (M, N) segment lengths; mask: (M, N) bool; R: (M, 3, 3) initial rotations (columns: VP
            directions); inlier_deg: inlier angle, degrees; iterations: steps, each with the inliers chosen again.

    Returns:
        (M, 3, 3) rotations; a row with fewer than 6 inliers keeps its rotation.
    """
    tol = math.sin(math.radians(inlier_deg)) ** 2
    n = cam.normals  # (M, N, 3)
    for _ in range(iterations):
        d = R.transpose(1, 2)  # (M, 3, 3): row j is VP direction j
        sin2 = squared_sines(cam, d)  # (M, 3, N)
        best, j = sin2.min(1)
        w = lengths * mask * (best < tol)  # (M, N)
        dj = d.gather(1, j[..., None].expand(-1, -1, 3))  # (M, N, 3) each segment's VP
        a = (n * dj).sum(-1)  # residual n . d
        b = torch.linalg.cross(dj, n)  # d(n . (d + w x d)) / dw = d x n
        A = torch.einsum("mn,mni,mnj->mij", w, b, b) + 1e-9 * torch.eye(3, dtype=R.dtype, device=R.device)
        g = torch.einsum("mn,mn,mni->mi", w, a, b)
        step = -torch.linalg.solve(A, g)
        ok = (w > 0).sum(-1) >= 6
        R = torch.where(ok[:, None, None], axis_angle_to_rotation_matrix(torch.where(ok[:, None], step, 0.0)) @ R, R)
    return R


def polish_frame(
    K: Tensor,
    R: Tensor,
    segments: Tensor,
    mask: Tensor,
    scales: tuple[float, ...] = PolishSettings().scales,
    inlier_deg: float = 1.5,
    kernel_deg: float = 1.0,
    iterations: int = 3,
    focal_margin: float = 0.01,
) -> tuple[Tensor, Tensor, Tensor]:
    """The polished ``K`` (B, 3, 3) and ``R`` (B, 3, 3), and (B,) bool where they replace the given ones.

    Args:
        K: (B, 3, 3) intrinsics of the frame search; R: (B, 3, 3) its rotation (columns: VP directions).
        segments: (B, N, 2, 2) pixels; mask: (B, N) bool.
        scales: focal scales tried (1 included); inlier_deg: inlier angle of the fit, degrees; kernel_deg: the
            support's kernel width, degrees; iterations: Gauss-Newton steps, each with the inliers chosen again;
            focal_margin: another scale replaces 1 only where its support is higher by more than this (relative).
    """
    B, S = len(K), len(scales)
    seg = segments.to(K.dtype)
    cam, lengths = camera_segments(seg, K), segment_lengths(seg, mask)
    scale = torch.tensor(scales, dtype=K.dtype, device=K.device)
    inv = (1.0 / scale)[:, None, None, None]
    stretch = torch.cat([1.0 / inv, 1.0 / inv, torch.ones_like(inv)], -1)
    cam_s = scaled_camera_segments(cam, inv, stretch)  # (S * B) rows, scale-major
    lengths_s, mask_s = lengths.repeat(S, 1), mask.repeat(S, 1)
    R_s = refit_rotation(cam_s, lengths_s, mask_s, R.repeat(S, 1, 1), inlier_deg, iterations)
    total = lengths.sum(-1).clamp_min(1e-12)
    support = (closeness_kernel(cam_s, R_s.transpose(1, 2)[:, None], kernel_deg, mask_s)[:, 0] * lengths_s).sum(-1)
    support = (support.view(S, B) / total).T  # (B, S)
    frame = (closeness_kernel(cam, R.transpose(1, 2)[:, None], kernel_deg, mask)[:, 0] * lengths).sum(-1) / total
    best_support, best = support.max(-1)
    # another focal length only where it explains clearly more: with one finite horizontal VP the support is flat
    # in the focal length, and its noise would move the answer
    one = torch.tensor(scales.index(1.0) if 1.0 in scales else 0, device=K.device)
    best = torch.where(best_support < support[:, one] * (1.0 + focal_margin), one, best)
    best_support = support.gather(1, best[:, None])[:, 0]
    use = best_support > frame
    R_best = R_s.view(S, B, 3, 3)[best, torch.arange(B)]
    K_best = scaled_focal(K, scale[best])
    R_out = torch.where(use[:, None, None], canonical_manhattan_rotation(R_best), R)
    return torch.where(use[:, None, None], K_best, K), R_out, use
