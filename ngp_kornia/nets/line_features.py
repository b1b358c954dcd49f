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

import functools
import math
from typing import NamedTuple

import numpy as np
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
_APART = ((_BINS @ _BINS.T).abs() > math.cos(math.radians(12.0))).numpy()


class _Shared(NamedTuple):
    """What several features of the segments share, computed once per call."""

    segments: Tensor  # (B, N, 2, 2) at the working resolution
    mid: Tensor  # (B, N, 2) midpoints
    u: Tensor  # (B, N, 2) unit directions, (1, 0) for a zero-length segment
    length: Tensor  # (B, N)


class _Constants(NamedTuple):
    """Constants of one dtype and device (:func:`_constants`)."""

    unit_x: Tensor  # (2,) the direction of a zero-length segment
    bins: Tensor  # (D, 3) the vote's directions
    eye: Tensor  # (3, 3) 1e-9 * identity: keeps the refinement's eigenproblem regular


class _Layout(NamedTuple):
    """Constants of one working resolution, dtype and device (:func:`_layout`)."""

    centre: Tensor  # (2,) the image centre
    scale: Tensor  # (2,) what maps a midpoint's doubled x and y to 0..2
    cell_low: Tensor  # (2,) and cell_high: the clamp of a midpoint's cell column and row
    cell_high: Tensor
    turns: Tensor  # (2,) orientation bins per radian: the crowding counts' and the Hough grid's
    last_turn: Tensor  # (2,) the last of those bins
    flip: Tensor  # (2,) (-1, 1): a direction (x, y) flipped, times this, is its normal (-y, x)
    steps: Tensor  # (3, 1, 1, 9) the 3x3 neighbours of a bin in each of the three flat grids
    grid: tuple[int, int, int]  # cells of the padded grid, its row length, the Hough grid's row length


# built once for each dtype and device, or working resolution: creating small tensors costs more than using them
@functools.lru_cache(maxsize=16)
def _constants(dtype: torch.dtype, device: torch.device) -> _Constants:
    with torch.inference_mode(False):  # plain tensors, usable in and out of inference mode
        kw = {"dtype": dtype, "device": device}
        return _Constants(_UNIT_X.to(**kw), _BINS.to(**kw), 1e-9 * torch.eye(3, **kw))


@functools.lru_cache(maxsize=16)
def _layout(height: int, width: int, dtype: torch.dtype, device: torch.device) -> _Layout:
    gh, gw = -(-height // _CELL) + 2, -(-width // _CELL) + 2  # padded by one cell on every side
    rho = 2 * (int(math.ceil(math.hypot(height, width) / 8.0)) + 2) + 1
    with torch.inference_mode(False):
        kw = {"dtype": dtype, "device": device}
        steps = torch.tensor([[-s - 1, -s, -s + 1, -1, 0, 1, s - 1, s, s + 1] for s in (gw, gw, rho)], device=device)
        return _Layout(
            image_center(height, width, like=torch.empty(0, **kw)),
            torch.tensor([max(width - 1, 1), max(height - 1, 1)], **kw), torch.zeros(2, **kw),
            torch.tensor([gw - 3, gh - 3], **kw),
            torch.tensor([_ORIENTATIONS / math.pi, 90 / math.pi], **kw),
            torch.tensor([_ORIENTATIONS - 1, 89], device=device), torch.tensor([-1.0, 1.0], **kw),
            steps[:, None, None], (gh * gw, gw, rho))


@functools.lru_cache(maxsize=16)
def _offsets(batch: int, grid: tuple[int, int, int], device: torch.device) -> Tensor:
    """Where each image's part of each of the three flat grids starts (3, B, 1), and the padding of the cell grids
    and the Hough grid's rows (a cell (0, 0) is at (1, 1), a distance bin -span at 0, an angle bin 0 in row 1)."""
    cells, row_length, rho_bins = grid
    with torch.inference_mode(False):
        image = torch.arange(batch)[:, None]
        hough = (image * 92 + 1) * rho_bins + rho_bins // 2 + batch * (_ORIENTATIONS + 1) * cells
        cell_grids = [image * cells, (image * _ORIENTATIONS + batch) * cells]
        return torch.stack([g + row_length + 1 for g in cell_grids] + [hough]).to(device)


def _shared(segments: Tensor) -> _Shared:
    """The quantities of the segments (B, N, 2, 2) that the features share (:class:`_Shared`)."""
    d = segments[..., 1, :] - segments[..., 0, :]
    length = d.norm(dim=-1)
    unit_x = _constants(d.dtype, d.device).unit_x
    u = torch.where(length[..., None] > 1e-6, d / length.clamp_min(1e-6)[..., None], unit_x)
    return _Shared(segments, segments.mean(-2), u, length)


def geometry_features(segments: Tensor, height: int, width: int) -> Tensor:
    """Length (log of working pixels), orientation (cos and sin of twice its angle) and midpoint (-1..1 across the
    image, y down) of each segment: (B, N, 2, 2) -> (B, N, 5)."""
    return _geometry(_shared(segments), _layout(height, width, segments.dtype, segments.device))


def _geometry(s: _Shared, lay: _Layout) -> Tensor:
    u0, u1 = s.u.unbind(-1)
    turn = torch.stack([u0 * u0 - u1 * u1, 2 * u0 * u1], -1)
    return torch.cat([(torch.log1p(s.length) / math.log(WORKING_SIZE))[..., None], turn,
                      2 * s.mid / lay.scale - 1], -1)


def _bins(s: _Shared, lay: _Layout) -> Tensor:
    """The bin (3, B, N) of each segment in the three flat grids: its cell, its cell and orientation, its Hough bin
    (the normal's angle in 2 degree bins, the distance from the image centre in 4 pixel bins). The grids lie one
    after the other in one flat tensor: B padded cell grids, 12 B of them (one per orientation), B Hough grids."""
    cells, row_length, rho_bins = lay.grid
    span = rho_bins // 2
    col, row = (s.mid / _CELL).floor().clamp(lay.cell_low, lay.cell_high).long().unbind(-1)
    local = row * row_length + col
    raw = torch.atan2(s.u[..., 1], s.u[..., 0])
    turn, angle = ((raw % math.pi)[..., None] * lay.turns).long().clamp(max=lay.last_turn).unbind(-1)
    rho = ((s.mid - lay.centre) * (s.u.flip(-1) * lay.flip)).sum(-1)  # along the normal
    rho = torch.where(raw < 0, -rho, rho)  # the same for both directions of a segment
    r_bin = (rho / 4.0).round().long().clamp(1 - span, span - 1)
    offsets = _offsets(s.length.shape[0], lay.grid, local.device)
    return torch.stack([local, turn * cells + local, angle * rho_bins + r_bin]) + offsets


def _neighbourhood(s: _Shared, mask: Tensor, lay: _Layout) -> Tensor:
    """Crowding around each segment, counted on coarse grids (the cost grows with the segments, not their pairs):
    the other segments whose midpoints share its 3x3 block of cells of :data:`_CELL` pixels, those among them of
    about its orientation (the same bin of :data:`_ORIENTATIONS`), and the length of the others along about the same
    line (a Hough grid of 2 degrees by 4 pixels, each bin with its neighbours) over its own. (B, N, 3)."""
    b = mask.shape[0]
    valid = mask.to(s.length)
    weight = s.length * valid
    index = _bins(s, lay)
    size = b * ((_ORIENTATIONS + 1) * lay.grid[0] + 92 * lay.grid[2])
    grid = weight.new_zeros(size).index_add_(0, index.flatten(), torch.stack([valid, valid, weight]).flatten())
    around = grid.take(index[..., None] + lay.steps).sum(-1)  # (3, B, N): each bin with its 3x3 neighbours
    collinear = (around[2] - weight) / s.length.clamp_min(1.0)
    return torch.log1p(torch.cat([around[:2] - 1.0, collinear[None]]).permute(1, 2, 0).clamp_min(0.0))


def _refine(lines: Tensor, weights: Tensor, vps: Tensor, angle: float, eye: Tensor) -> Tensor:
    """Each VP (B, K, 3) moved to the least-squares point of the lines (B, N, 3) within ``angle`` degrees of it
    (kept where none is)."""
    near = ((vps @ lines.transpose(1, 2)).abs() < math.sin(math.radians(angle))) * weights[:, None]  # lengths >= 0
    weighted = near[..., None] * lines[:, None]  # (B, K, N, 3)
    tensor = weighted.transpose(-1, -2) @ lines[:, None]  # (B, K, 3, 3)
    refined = torch.linalg.eigh(tensor + eye)[1][..., :, 0]  # the direction the lines are most orthogonal to
    refined = torch.where((refined * vps).sum(-1, keepdim=True) < 0, -refined, refined)
    return torch.where(near.sum(-1, keepdim=True) > 0, refined, vps)


def _peaks(votes: Tensor) -> Tensor:
    """The :data:`_PEAKS` strongest bins (B, K) of the votes (B, D), greedily: the strongest, then none within 12
    degrees of it. A loop of a few steps on a few hundred numbers, in NumPy: its steps cost less than the dispatch
    of torch's."""
    left = votes.detach().to("cpu", torch.float64).numpy().copy()
    peaks = np.empty((len(left), _PEAKS), dtype=np.int64)
    for k in range(_PEAKS):
        peaks[:, k] = best = left.argmax(-1)
        left[_APART[best]] = -1.0
    return torch.from_numpy(peaks).to(votes.device)


def _dominant_vps(lines: Tensor, weights: Tensor) -> tuple[Tensor, Tensor]:
    """The :data:`_PEAKS` directions on the half sphere that the most line length of the :data:`_VOTERS` longest
    lines passes within 4 degrees of, each refined twice to the least-squares point of the lines near it: VPs
    (B, K, 3) in the pseudo camera and their support (B, K), the share of the image's line length within 1.5
    degrees of them. The weights (B, N) are lengths, 0 for padding (so a test times a weight is the weight where
    the test passes: about half the cost of ``where`` with a broadcast weight on the vote's 128 x 300 tests)."""
    top = weights.topk(min(_VOTERS, weights.shape[1]), dim=-1)
    voters = lines.gather(1, top.indices[..., None].expand(-1, -1, 3))
    const = _constants(lines.dtype, lines.device)
    hits = ((voters @ const.bins.T).abs() < math.sin(math.radians(4.0))) * top.values[..., None]
    vps = const.bins[_peaks(hits.sum(1))]
    vps = _refine(lines, weights, _refine(lines, weights, vps, 4.0, const.eye), 1.5, const.eye)
    close = (vps @ lines.transpose(1, 2)).abs() < math.sin(math.radians(1.5))
    support = (close * weights[:, None]).sum(-1) / weights.sum(-1, keepdim=True).clamp_min(1e-9)
    return vps, support


def _vanishing_features(s: _Shared, mask: Tensor, height: int, width: int, lay: _Layout) -> Tensor:
    """Angle (degrees / 10, at most 1) to the nearest and the second nearest dominant VP, the nearest one's support
    and how vertical it is in the pseudo camera (|y| of its unit vector): (B, N, 4)."""
    f = pseudo_focal(height, width)
    x0, y0, x1, y1 = ((s.segments - lay.centre) / f).flatten(-2).unbind(-1)
    lines = torch.stack([y0 - y1, x1 - x0, x0 * y1 - x1 * y0], -1)  # the cross product of the two ends
    lines = lines / lines.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    vps, support = _dominant_vps(lines, s.length * mask)
    pixel_vps = torch.cat([vps[..., :2] * f + lay.centre * vps[..., 2:], vps[..., 2:]], -1)
    nearest = segment_vp_angle(s.segments, pixel_vps).sort(dim=1)  # (B, K, N)
    first, second = (nearest.values[:, :2] / 10).clamp(max=1).unbind(1)
    of_first = torch.stack([support, vps[..., 1].abs()], -1).gather(1, nearest.indices[:, 0, :, None].expand(-1, -1, 2))
    return torch.stack([first, of_first[..., 0], of_first[..., 1], second], -1)


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
    return _context(_shared(segments), mask, _layout(height, width, segments.dtype, segments.device), height, width)


def _context(s: _Shared, mask: Tensor, lay: _Layout, height: int, width: int) -> Tensor:
    """:func:`context_features` from the shared quantities."""
    order = torch.where(mask, s.length, -1.0).argsort(-1, descending=True)
    ranks = torch.arange(mask.shape[1], dtype=s.length.dtype, device=mask.device).expand_as(s.length)
    rank = torch.empty_like(s.length).scatter_(-1, order, ranks)  # the inverse permutation of the order
    rank = rank / (mask.sum(-1, keepdim=True).clamp_min(2).to(rank) - 1)
    return torch.cat([_neighbourhood(s, mask, lay), rank.clamp(max=1)[..., None],
                      _vanishing_features(s, mask, height, width, lay)], -1)


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
    seg = torch.where(mask[..., None, None], segments.to(images.dtype), 0.0)
    seg, h, w = to_working_resolution(seg, *images.shape[-2:])
    shared, layout = _shared(seg), _layout(h, w, seg.dtype, seg.device)
    out = torch.cat([_geometry(shared, layout), _context(shared, mask, layout, h, w)], -1)
    return torch.where(mask[..., None], out, 0.0)
