"""The inputs of the line-evidence network: fixed, cheap features of each detected segment, pure batched functions.

Two groups, each a function of its own (:func:`segment_features` puts them together):

* :func:`geometry_features`: length, orientation, position in the image.
* :func:`context_features`: what the other segments of the image say: how crowded the segment's neighbourhood is,
  with parallel segments and along its own line, its rank by length, and whether it points at one of the image's
  dominant vanishing points (found by a small vote of the longest segments on the Gaussian sphere of the pseudo
  camera, then refined) and how much line length backs that point.

The image itself is not sampled: features of the image around each segment (its brightness profile across the
segment, the step's contrast and how it varies along it, the colour on both sides) were measured and gave a network
trained on renders nothing on York Urban's labelled segments (see BENCHMARKS.md), at a third of the stage's cost.

Everything is measured at the working resolution (long side :data:`WORKING_SIZE` pixels), so the same scene gives
the same features at any input size.
"""

from __future__ import annotations

import math

import torch
from kornia.geometry.conversions import pol2cart
from torch import Tensor

from ngp_kornia.geometry import image_center, pseudo_focal, segment_vp_angle

__all__ = [
    "FEATURE_NAMES",
    "WORKING_SIZE",
    "check_inputs",
    "context_features",
    "geometry_features",
    "segment_features",
    "sphere_directions",
    "to_working_resolution",
]

#: long side (pixels) of the resolution the features are measured at
WORKING_SIZE = 640
#: directions of the vote for vanishing points, the longest segments that vote, and the dominant VPs kept
_SPHERE_BINS, _VOTERS, _PEAKS = 300, 128, 6
#: cell size (pixels) and orientation bins of the crowding counts
_CELL, _ORIENTATIONS = 32, 12

_UNIT_X = torch.tensor([1.0, 0.0])

FEATURE_NAMES = (
    "log_length", "cos_2theta", "sin_2theta", "mid_x", "mid_y",
    "neighbours", "parallel_neighbours", "collinear_length", "length_rank",
    "vp_angle", "vp_support", "vp_vertical", "vp_angle_second",
)


def to_working_resolution(segments: Tensor, height: int, width: int) -> tuple[Tensor, int, int]:
    """Segments of an image of ``height`` x ``width`` mapped to the working resolution (long side
    :data:`WORKING_SIZE`, aspect ratio kept; pixel-centre convention), and that resolution's height and width.

    Example:
        >>> seg, h, w = to_working_resolution(torch.tensor([[[[-0.5, -0.5], [1279.5, 959.5]]]]), 960, 1280)
        >>> seg.tolist(), h, w
        ([[[[-0.5, -0.5], [639.5, 479.5]]]], 480, 640)
    """
    scale = WORKING_SIZE / max(height, width)
    if scale == 1.0:
        return segments, height, width
    h, w = max(1, round(height * scale)), max(1, round(width * scale))
    factor = torch.tensor([w / width, h / height], dtype=segments.dtype, device=segments.device)
    return (segments + 0.5) * factor - 0.5, h, w


def _frames(segments: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Start (B, N, 2), unit direction (B, N, 2), unit normal (B, N, 2) and length (B, N) of each segment; a
    zero-length segment gets the direction (1, 0)."""
    start, d = segments[..., 0, :], segments[..., 1, :] - segments[..., 0, :]
    length = d.norm(dim=-1)
    u = torch.where(length[..., None] > 1e-6, d / length.clamp_min(1e-6)[..., None], _UNIT_X.to(d))
    return start, u, torch.stack([-u[..., 1], u[..., 0]], -1), length


def geometry_features(segments: Tensor, height: int, width: int) -> Tensor:
    """Length (log of working pixels), orientation (cos and sin of twice its angle) and midpoint (-1..1 across the
    image, y down) of each segment: (B, N, 2, 2) -> (B, N, 5)."""
    _, u, _, length = _frames(segments)
    mid = segments.mean(-2)
    cos2, sin2 = u[..., 0] ** 2 - u[..., 1] ** 2, 2 * u[..., 0] * u[..., 1]
    x = 2 * mid[..., 0] / max(width - 1, 1) - 1
    y = 2 * mid[..., 1] / max(height - 1, 1) - 1
    return torch.stack([torch.log1p(length) / math.log(WORKING_SIZE), cos2, sin2, x, y], -1)


def _around(grid: Tensor, index: Tensor, stride: int) -> Tensor:
    """The sum of a flat padded grid over the 3x3 bins around each index (B, N) (``stride``: its row length)."""
    steps = torch.tensor([-stride - 1, -stride, -stride + 1, -1, 0, 1, stride - 1, stride, stride + 1],
                         device=index.device)
    return grid.gather(0, (index[..., None] + steps).flatten()).reshape(*index.shape, 9).sum(-1)


def _neighbourhood(segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
    """Crowding around each segment, counted on coarse grids (the cost grows with the segments, not their pairs):
    the other segments whose midpoints share its 3x3 block of cells of :data:`_CELL` pixels, those among them of
    about its orientation (the same bin of :data:`_ORIENTATIONS`), and the length of the others along about the same
    line (a Hough grid of 2 degrees by 4 pixels, each bin with its neighbours) over its own. (B, N, 3)."""
    b = mask.shape[0]
    _, u, normal, length = _frames(segments)
    valid = mask.to(length).flatten()
    mid = segments.mean(-2)
    image = torch.arange(b, device=mask.device)[:, None]
    # cells, padded by one on every side so that the 3x3 block around any cell exists
    gh, gw = -(-height // _CELL) + 2, -(-width // _CELL) + 2
    row = (mid[..., 1] / _CELL).floor().clamp(0, gh - 3).long() + 1
    col = (mid[..., 0] / _CELL).floor().clamp(0, gw - 3).long() + 1
    raw = torch.atan2(u[..., 1], u[..., 0])
    theta = raw % math.pi
    turn = (theta * (_ORIENTATIONS / math.pi)).long().clamp(max=_ORIENTATIONS - 1)
    cell = (image * gh + row) * gw + col
    near = _around(valid.new_zeros(b * gh * gw).index_add_(0, cell.flatten(), valid), cell, gw) - 1.0
    cell = cell + (image * (_ORIENTATIONS - 1) + turn) * gh * gw  # into (B, orientations, gh, gw)
    same = _around(valid.new_zeros(b * _ORIENTATIONS * gh * gw).index_add_(0, cell.flatten(), valid), cell, gw) - 1.0
    # the Hough grid: the normal's angle in 2 degree bins, the distance from the image centre in 4 pixel bins
    span = int(math.ceil(math.hypot(height, width) / 8.0)) + 2
    centre = image_center(height, width, like=mid)
    rho = ((mid - centre) * normal).sum(-1)
    rho = torch.where(raw < 0, -rho, rho)  # the same for both directions of a segment
    r_bin = (rho / 4.0).round().long().clamp(1 - span, span - 1) + span
    a_bin = (theta * (90 / math.pi)).long().clamp(max=89) + 1
    line = (image * 92 + a_bin) * (2 * span + 1) + r_bin
    weight = length.flatten() * valid
    along = _around(weight.new_zeros(b * 92 * (2 * span + 1)).index_add_(0, line.flatten(), weight), line, 2 * span + 1)
    collinear = (along - length * mask) / length.clamp_min(1.0)
    return torch.log1p(torch.stack([near, same, collinear], -1).clamp_min(0.0))


def sphere_directions(count: int = _SPHERE_BINS) -> Tensor:
    """(count, 3) unit directions spread evenly over the half sphere ``z >= 0`` (a Fibonacci lattice): the bins of
    the vanishing-point vote.

    Example:
        >>> d = sphere_directions(100)
        >>> tuple(d.shape), bool((d[:, 2] >= 0).all()), bool(torch.allclose(d.norm(dim=-1), torch.ones(100)))
        ((100, 3), True, True)
    """
    k = torch.arange(count, dtype=torch.float64) + 0.5
    z = 1.0 - k / count
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = (1.0 - z * z).sqrt()
    return torch.stack([*pol2cart(r, phi), z], -1).float()


_BINS = sphere_directions()
#: pairs of bins too close (within 12 degrees) to be two peaks of the vote
_APART = (_BINS @ _BINS.T).abs() > math.cos(math.radians(12.0))


def _refine(lines: Tensor, weights: Tensor, vps: Tensor, angle: float) -> Tensor:
    """Each VP (B, K, 3) moved to the least-squares point of the lines (B, N, 3) within ``angle`` degrees of it
    (kept where none is)."""
    near = torch.where((vps @ lines.transpose(1, 2)).abs() < math.sin(math.radians(angle)), weights[:, None], 0.0)
    weighted = near[..., None] * lines[:, None]  # (B, K, N, 3)
    tensor = weighted.transpose(-1, -2) @ lines[:, None]  # (B, K, 3, 3)
    eye = torch.eye(3, dtype=lines.dtype, device=lines.device)
    refined = torch.linalg.eigh(tensor + 1e-9 * eye)[1][..., :, 0]  # the direction the lines are most orthogonal to
    refined = torch.where((refined * vps).sum(-1, keepdim=True) < 0, -refined, refined)
    return torch.where(near.sum(-1, keepdim=True) > 0, refined, vps)


def _dominant_vps(lines: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """The :data:`_PEAKS` directions on the half sphere that the most line length of the :data:`_VOTERS` longest
    lines passes within 4 degrees of, each refined twice to the least-squares point of the lines near it: VPs
    (B, K, 3) in the pseudo camera and their support (B, K), the share of the image's line length within 1.5
    degrees of them."""
    top = weights.topk(min(_VOTERS, weights.shape[1]), dim=-1)
    voters = lines.gather(1, top.indices[..., None].expand(-1, -1, 3))
    bins, apart = _BINS.to(lines), _APART.to(lines.device)
    hits = torch.where((voters @ bins.T).abs() < math.sin(math.radians(4.0)), top.values[..., None], 0.0)
    votes = hits.sum(1)  # (B, D)
    peaks = []
    for _ in range(_PEAKS):  # greedy: the strongest bin, then none near it
        best = votes.argmax(-1)
        peaks.append(best)
        votes = votes.masked_fill(apart[best], -1.0)
    vps = _refine(lines, weights, _refine(lines, weights, bins[torch.stack(peaks, -1)], 4.0), 1.5)
    close = (vps @ lines.transpose(1, 2)).abs() < math.sin(math.radians(1.5))
    support = torch.where(close, weights[:, None], 0.0).sum(-1) / weights.sum(-1, keepdim=True).clamp_min(1e-9)
    return vps, support


def _vanishing_features(segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
    """Angle (degrees / 10, at most 1) to the nearest and the second nearest dominant VP, the nearest one's support
    and how vertical it is in the pseudo camera (|y| of its unit vector): (B, N, 4)."""
    f = pseudo_focal(height, width)
    centre = image_center(height, width, like=segments)
    x0, y0, x1, y1 = ((segments - centre) / f).flatten(-2).unbind(-1)
    lines = torch.stack([y0 - y1, x1 - x0, x0 * y1 - x1 * y0], -1)  # the cross product of the two ends
    lines = lines / lines.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    length = (segments[..., 1, :] - segments[..., 0, :]).norm(dim=-1) * mask.to(segments)
    vps, support = _dominant_vps(lines, length)
    pixel_vps = torch.cat([vps[..., :2] * f + centre * vps[..., 2:], vps[..., 2:]], -1)
    angle = segment_vp_angle(segments, pixel_vps)  # (B, K, N)
    order = angle.argsort(dim=1)
    first, second = angle.gather(1, order[:, :1])[:, 0], angle.gather(1, order[:, 1:2])[:, 0]
    best_support = support.gather(1, order[:, 0])
    vertical = vps[..., 1].abs().gather(1, order[:, 0])
    return torch.stack([(first / 10).clamp(max=1), best_support, vertical, (second / 10).clamp(max=1)], -1)


def context_features(segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
    """What the image's other segments say about each one: crowding (:func:`_neighbourhood`), its rank by length
    (0 the longest, 1 the shortest) and its relation to the dominant vanishing points.

    Args:
        segments: (B, N, 2, 2) pixels at the working resolution.
        mask: (B, N) bool, False for padding (ignored by the others).
        height: image height at the working resolution.
        width: its width.

    Returns:
        (B, N, 8).
    """
    length = (segments[..., 1, :] - segments[..., 0, :]).norm(dim=-1)
    ranked = torch.where(mask, length, torch.full_like(length, -1.0))
    rank = ranked.argsort(-1, descending=True).argsort(-1).to(length)
    count = mask.sum(-1, keepdim=True).clamp_min(2).to(length)
    rank = rank / (count - 1)
    return torch.cat([_neighbourhood(segments, mask, height, width), rank.clamp(max=1)[..., None],
                      _vanishing_features(segments, mask, height, width)], -1)


def check_inputs(images: Tensor, segments: Tensor, mask: Tensor) -> None:
    """Raise a one-line error naming what is wrong with the inputs of :func:`segment_features`.

    Raises:
        TypeError: non-tensors, integer images, a mask that is not boolean.
        ValueError: shapes other than (B, 3, H, W), (B, N, 2, 2) and (B, N) with one B and one N.
    """
    for name, value in (("images", images), ("segments", segments), ("mask", mask)):
        if not isinstance(value, Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if not images.is_floating_point():
        raise TypeError(f"images must be floating point RGB in [0, 1], got {images.dtype}; divide uint8 images by 255")
    if mask.dtype != torch.bool:
        raise TypeError(f"mask must be a bool tensor, got {mask.dtype}")
    if images.ndim != 4 or images.shape[1] != 3:
        raise ValueError(f"images must be (B, 3, H, W) RGB, got shape {tuple(images.shape)}")
    if segments.ndim != 4 or segments.shape[2:] != (2, 2):
        raise ValueError(f"segments must be (B, N, 2, 2) [[x0, y0], [x1, y1]], got shape {tuple(segments.shape)}")
    if mask.shape != segments.shape[:2] or images.shape[0] != segments.shape[0]:
        raise ValueError(f"images {tuple(images.shape)}, segments {tuple(segments.shape)} and mask "
                         f"{tuple(mask.shape)} must share B (and segments and mask N)")


def segment_features(images: Tensor, segments: Tensor, mask: Tensor) -> Tensor:
    """All the features of each segment, :data:`FEATURE_NAMES` in order; zeros where ``mask`` is False.

    Args:
        images: (B, 3, H, W) RGB in [0, 1] (their size sets the working resolution).
        segments: (B, N, 2, 2) pixels ``[[x0, y0], [x1, y1]]`` of those images.
        mask: (B, N) bool.

    Returns:
        (B, N, len(FEATURE_NAMES)) in the images' dtype. An image's features do not depend on the other images of
        its batch.

    Example:
        >>> images = torch.rand(2, 3, 48, 64)
        >>> segments = torch.tensor([[[10.0, 5.0], [10.0, 40.0]], [[5.0, 20.0], [60.0, 22.0]]]).expand(2, 2, 2, 2)
        >>> features = segment_features(images, segments, torch.tensor([[True, True], [True, False]]))
        >>> features.shape[:2], features.shape[2] == len(FEATURE_NAMES), features[1, 1].abs().sum().item()
        (torch.Size([2, 2]), True, 0.0)
    """
    check_inputs(images, segments, mask)
    if segments.shape[1] == 0:
        return images.new_zeros(images.shape[0], 0, len(FEATURE_NAMES))
    seg = torch.where(mask[..., None, None], segments.to(images.dtype), torch.zeros_like(segments, dtype=images.dtype))
    seg, h, w = to_working_resolution(seg, *images.shape[-2:])
    out = torch.cat([geometry_features(seg, h, w), context_features(seg, mask, h, w)], -1)
    return torch.where(mask[..., None], out, torch.zeros_like(out))
