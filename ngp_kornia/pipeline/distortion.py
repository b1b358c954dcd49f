"""Radial distortion from the curvature of long lines: the division model's coefficient that makes chained segments
straight again (:mod:`ngp_kornia.geometry.lens`).

A straight edge of the world is straight in a pinhole photo; through a lens with radial distortion it bends, and
LSD, which fits straight segments, cuts it into a chain of pieces that meet at small angles. Undistorted with the
right coefficient, the pieces fall on one line again. The estimate needs no calibration: the coefficient ``lam``
works in the pseudo camera's units (``q = (p - c) / s``, ``s`` half the long side, ``c`` the distortion centre,
the principal point), ``q_u = q_d / (1 + lam |q_d|^2)``; the focal-length units of :mod:`~ngp_kornia.geometry.lens`
follow once the focal length is known (:func:`~ngp_kornia.geometry.lens.coefficient_from_pseudo`).

1. **Chained pairs.** Two segments form a pair when an endpoint of one lies within ``gap`` (pseudo units) of an
   endpoint of the other, their directions differ by less than ``angle_deg``, and they continue each other (the
   near endpoints are the ends that face each other, so the pieces do not overlap). The ``max_pairs`` longest
   pairs count.
2. **Straightness.** For each coefficient of a grid (:data:`COARSE` times ``step`` apart over ``search_low`` ..
   ``search_high``, then ``step`` apart around the best of those), the pair's four
   endpoints are undistorted and each piece's line is compared with the other piece's endpoints
   (:func:`distortion_costs`): the mean squared sine of those angles, truncated at ``tolerance_deg`` (two pieces
   of different lines that happen to meet count the same for every coefficient), weighed by the pair's length.
3. **The answer.** The coefficient of the least summed cost, refined by a parabola through its neighbours; an image
   with fewer than ``min_pairs`` pairs, whose least cost lies at an end of the search, or whose least cost is not
   below the cost without distortion by more than ``min_gain`` of the cost of the pairs straight at either (pairs
   crooked at both say nothing), keeps 0 (no evidence, no distortion).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ngp_kornia.pipeline.settings import DistortionSettings

__all__ = [
    "COARSE",
    "chained_pairs",
    "distortion_costs",
    "estimate_distortion",
    "joint_distortion",
]


#: the first search's step, in steps of the second's (which spans this many steps either side of its best)
COARSE = 5


def _ends(q: Tensor) -> tuple[Tensor, Tensor]:
    """Start and end points (B, N, 2) of (B, N, 2, 2) segments."""
    return q[..., 0, :], q[..., 1, :]


def chained_pairs(q: Tensor, mask: Tensor, settings: DistortionSettings) -> tuple[Tensor, Tensor, Tensor]:
    """Step 1 of the module docstring on segments ``q`` (B, N, 2, 2) in pseudo units with their (B, N) mask.

    Returns:
        the first and second segment of each pair (B, P) long, and (B, P) weights: the pair's length, 0 for
        padding (P at most ``max_pairs``).
    """
    B, N = mask.shape
    start, end = _ends(q)
    direction = end - start
    length = torch.linalg.vector_norm(direction, dim=-1)
    unit = direction / length[..., None].clamp_min(1e-12)
    ends = torch.stack([start, end], 2)  # (B, N, 2, 2)
    # every endpoint against every endpoint: (B, N, 2, N, 2) distances
    gaps = torch.linalg.vector_norm(ends[:, :, :, None, None] - ends[:, None, None], dim=-1)
    gap, which = gaps.flatten(-2).permute(0, 1, 3, 2).reshape(B, N, N, 4).min(-1)  # (B, N, N), endpoint combo
    cosine = (unit[:, :, None] * unit[:, None]).sum(-1).abs()
    near_i, near_j = which // 2, which % 2  # 0: the start, 1: the end of segment i (j)
    # pieces that continue each other face each other: i's near end points away from i, towards j's far side
    sign_i = torch.where(near_i == 1, 1.0, -1.0).to(q)
    sign_j = torch.where(near_j == 1, 1.0, -1.0).to(q)
    facing = ((unit[:, :, None] * sign_i[..., None]) * (unit[:, None] * -sign_j[..., None])).sum(-1) > 0
    ok = (gap < settings.gap) & (cosine > math.cos(math.radians(settings.angle_deg))) & facing
    ok = ok & mask[:, :, None] & mask[:, None] & torch.triu(torch.ones(N, N, dtype=torch.bool, device=q.device), 1)
    weight = torch.where(ok, length[:, :, None] + length[:, None], torch.zeros_like(gap))
    count = min(settings.max_pairs, N * N)
    top = weight.flatten(1).topk(count, dim=-1)
    return top.indices // N, top.indices % N, top.values


def distortion_costs(q: Tensor, first: Tensor, second: Tensor, lams: Tensor) -> Tensor:
    """Step 2 of the module docstring: each pair's straightness at each coefficient, (B, G, P).

    A pair is straight when each piece's two endpoints lie on the other piece's line: the cost is the mean of the
    four squared sines of the angles, seen from each piece's midpoint, between its line and the other piece's
    endpoints. Angles do not change when undistorting shrinks or grows the whole image, which distances would.

    Args:
        q: (B, N, 2, 2) segments in pseudo units; first, second: (B, P) the pairs; lams: (G,) coefficients, or
            (B, G), each image its own.
    """
    B, P = first.shape
    index = torch.stack([first, second], -1)  # (B, P, 2)
    points = q.gather(1, index.reshape(B, 2 * P, 1, 1).expand(B, 2 * P, 2, 2)).reshape(B, P, 2, 2, 2)
    r2 = points.square().sum(-1, keepdim=True)
    scale = (1.0 + lams.to(q).reshape(-1 if lams.dim() == 2 else 1, lams.shape[-1], 1, 1, 1, 1) * r2[:, None])
    scale = scale.clamp_min(1e-6)
    u = points[:, None] / scale  # (B, G, P, piece, end, 2)
    mid = u.mean(-2)  # (B, G, P, 2, 2)
    direction = u[..., 1, :] - u[..., 0, :]
    unit = direction / torch.linalg.vector_norm(direction, dim=-1, keepdim=True).clamp_min(1e-12)
    other = u.flip(-3)  # each piece's partner's endpoints
    ray = other - mid[..., None, :]  # (B, G, P, piece, end, 2)
    cross = unit[..., None, 0] * ray[..., 1] - unit[..., None, 1] * ray[..., 0]
    sines = cross / torch.linalg.vector_norm(ray, dim=-1).clamp_min(1e-12)
    return sines.square().mean((-1, -2))


def estimate_distortion(
    segments: Tensor, mask: Tensor, centre: Tensor, height: int, width: int, settings: DistortionSettings | None = None
) -> Tensor:
    """The coefficient ``lam`` (B,) in pseudo units that makes the chained segments straightest (module docstring).

    Args:
        segments: (B, N, 2, 2) segments in the photo's (distorted) pixels; mask: (B, N) bool.
        centre: (B, 2) the distortion centre (the principal point), pixels.
        height, width: the photo's size.
        settings: the chaining and the search; None for the defaults.

    Returns:
        (B,) coefficients in units of half the long side
        (:func:`~ngp_kornia.geometry.lens.coefficient_from_pseudo` converts them); 0 where fewer than ``min_pairs``
        pairs were found.

    Example:
        >>> seg = torch.tensor([[[[0.0, 0.0], [50.0, 0.0]]]])
        >>> estimate_distortion(seg, torch.ones(1, 1, dtype=torch.bool), torch.tensor([[32.0, 24.0]]), 48, 64)
        tensor([0.])
    """
    settings = settings or DistortionSettings()
    q = (segments.double() - centre.double()[:, None, None]) / (max(height, width) / 2.0)
    first, second, weight = chained_pairs(q, mask, settings)
    cap = math.sin(math.radians(settings.tolerance_deg)) ** 2

    def pair_costs(lams: Tensor) -> Tensor:  # (B, G, P) truncated costs at (G,) or (B, G) coefficients
        return distortion_costs(q, first, second, lams).clamp_max(cap)

    # coarse (COARSE steps apart, 0 among them), then ``step`` apart around the coarse best
    coarse_step = COARSE * settings.step
    below, above = round(-settings.search_low / coarse_step), round(settings.search_high / coarse_step)
    coarse = torch.arange(-below, above + 1, dtype=torch.float64, device=q.device) * coarse_step
    per_pair = pair_costs(coarse)
    coarse_cost = (per_pair * weight[:, None]).sum(-1)
    at = coarse_cost.argmin(-1)
    fine = coarse[at][:, None] + torch.arange(-COARSE, COARSE + 1).to(q) * settings.step
    fine_cost = (pair_costs(fine) * weight[:, None]).sum(-1)
    lam = _parabola_minimum(fine, fine_cost, settings.step)
    # a coefficient only where it straightens clearly more than none does, counting the pairs that are straight at
    # either (those crooked at both are two lines met by chance): a flat cost (pairs near the centre, along radii,
    # or a lens without distortion) has its minimum anywhere, and one at the search's ends is no minimum
    rows = torch.arange(len(q), device=q.device)
    none, best = per_pair[:, below], per_pair[rows, at]
    junk = ((none >= cap) & (best >= cap)).to(none) * cap * weight
    informative = (none * weight - junk).sum(-1)
    gain = (coarse_cost[:, below] - fine_cost.amin(-1)) / informative.clamp_min(1e-300)
    inside = (at > 0) & (at < len(coarse) - 1)
    enough = ((weight > 0).sum(-1) >= settings.min_pairs) & (gain > settings.min_gain) & inside
    return torch.where(enough, lam, torch.zeros_like(lam)).to(segments.dtype)


def _parabola_minimum(lams: Tensor, cost: Tensor, step: float) -> Tensor:
    """The coefficient (B,) of the least of (B, G) costs at (B, G) coefficients ``step`` apart, refined by a parabola
    through it and its neighbours (the grid point itself at the grid's ends)."""
    i = cost.argmin(-1)
    inner = i.clamp(1, cost.shape[-1] - 2)
    y0, y1, y2 = (cost.gather(1, (inner + d)[:, None])[:, 0] for d in (-1, 0, 1))
    curve = y0 - 2.0 * y1 + y2
    offset = torch.where(curve > 0, 0.5 * (y0 - y2) / curve.clamp_min(1e-300), torch.zeros_like(curve))
    lam = lams.gather(1, inner[:, None])[:, 0] + offset.clamp(-0.5, 0.5) * step
    return torch.where((i == inner) & torch.isfinite(lam), lam, lams.gather(1, i[:, None])[:, 0])


def joint_distortion(values: Tensor) -> float:
    """One camera's distortion from each photo's own estimate (P,): the median of those that found one (an
    estimate of 0 is a photo without evidence), 0 when none did."""
    found = values[values != 0]
    return float(found.median()) if len(found) else 0.0
