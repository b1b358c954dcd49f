"""Detected segments against hand-labelled ones (York Urban's ``LinesAndVP.mat``): which detected segments lie on
a labelled line, and which vanishing point that line was labelled with.

A detected segment *matches* when at least half of its length lies within ``max_distance`` pixels of labelled
segments whose direction is within ``max_angle`` degrees of its own (16 points along it are checked). The labelled
segment covering most of those points names its vanishing point.
"""

from __future__ import annotations

import math

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

__all__ = ["labelled_directions", "match_segments"]


def match_segments(detected: Tensor, labelled: Tensor, max_distance: float = 3.0, max_angle: float = 3.0,
                   min_share: float = 0.5, points: int = 16) -> tuple[Tensor, Tensor]:
    """Match detected segments to labelled ones.

    Args:
        detected: (N, 2, 2) pixels.
        labelled: (M, 2, 2) pixels.
        max_distance: largest distance (pixels) from a point of the detected segment to a labelled segment.
        max_angle: largest angle (degrees) between the two segments' directions.
        min_share: least share of the detected segment's points within reach.
        points: points checked along each detected segment, ends included.

    Returns:
        matched (N,) bool, and (N,) int64 the index of the labelled segment covering most of each one (-1 where
        none matches).

    Example:
        >>> labelled = torch.tensor([[[0.0, 0.0], [100.0, 0.0]]])
        >>> detected = torch.tensor([[[10.0, 1.0], [60.0, 2.0]], [[10.0, 8.0], [60.0, 8.0]],
        ...                          [[90.0, 0.0], [130.0, 0.0]]])
        >>> match_segments(detected, labelled)
        (tensor([ True, False, False]), tensor([ 0, -1, -1]))
    """
    KORNIA_CHECK_SHAPE(detected, ["N", "2", "2"])
    KORNIA_CHECK_SHAPE(labelled, ["M", "2", "2"])
    det, lab = detected.double(), labelled.double()
    n = det.shape[0]
    if n == 0 or lab.shape[0] == 0:
        return torch.zeros(n, dtype=torch.bool), torch.full((n,), -1, dtype=torch.long)
    t = torch.linspace(0.0, 1.0, points, dtype=det.dtype)
    at = det[:, None, 0] + t[None, :, None] * (det[:, None, 1] - det[:, None, 0])  # (N, P, 2)
    a, ab = lab[:, 0], lab[:, 1] - lab[:, 0]
    s = (((at[:, :, None] - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    dist = (at[:, :, None] - (a + s[..., None] * ab)).norm(dim=-1)  # (N, P, M)
    d = det[:, 1] - det[:, 0]
    cos = (d @ ab.T).abs() / (d.norm(dim=-1)[:, None] * ab.norm(dim=-1)[None]).clamp_min(1e-12)
    near = (dist <= max_distance) & (cos >= math.cos(math.radians(max_angle)))[:, None]
    matched = near.any(-1).double().mean(-1) >= min_share
    best = near.sum(1).argmax(-1)
    return matched, torch.where(matched, best, torch.full_like(best, -1))


def labelled_directions(vp_index: Tensor, vertical: int = 1) -> Tensor:
    """Direction classes (0 vertical, 1 horizontal) of labelled segments from the vanishing point they were labelled
    with: York Urban's column ``vertical`` (0-based: 1, the database's column 2) is the vertical, the other two are
    horizontal. (M,) -> (M,) int64.

    Example:
        >>> labelled_directions(torch.tensor([0, 1, 2]))
        tensor([1, 0, 1])
    """
    return torch.where(vp_index == vertical, 0, 1).long()
