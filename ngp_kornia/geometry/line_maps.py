r"""Rasterised line maps (Eq. 13), closeness maps (Eq. 15) and the map form of the Manhattan score (Eq. 21).

Segments are drawn by sampling points about one pixel apart along each segment and writing each segment's
value into the nearest pixel; where segments overlap a pixel keeps the largest value. The maps are
differentiable with respect to the per-segment values (so closeness maps pass gradients to the VPs). Ours:
kornia's ``draw_line`` paints lines into one (C, H, W) image in one colour, refusing endpoints outside it, with no
per-segment values or gradients.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import torch
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry.camera import image_center

__all__ = [
    "DrawnPixels",
    "closeness_maps",
    "drawn_pixels",
    "line_map",
    "line_map_and_pooled_maps",
    "manhattan_score_maps",
    "pooled_maps",
    "rasterize_segments",
]


def rasterize_segments(
    segments: Tensor, mask: Tensor, values: Tensor, height: int, width: int, chunk_channels: int = 96
) -> Tensor:
    """Draw segments into (B, C, H, W) maps, each pixel a segment passes through taking that segment's values.

    Every (segment, pixel) pair is written once per channel, so drawing the closeness maps of hundreds of frame
    candidates stays cheap.

    Args:
        segments: (B, N, 2, 2) segment endpoints in the map's pixels.
        mask: (B, N) bool, False for padding (not drawn).
        values: (B, N, C) non-negative per-segment values, one channel each.
        height: map height.
        width: map width.
        chunk_channels: channels scattered at once (bounds the index memory; all at once when ``values`` needs
            gradients, since the max's backward needs the untouched output).

    Returns:
        (B, C, H, W) maps, zero where no segment passes. Overlaps keep the maximum. Differentiable with respect to
        ``values``.

    Example:
        >>> seg = torch.tensor([[[[0.0, 1.0], [3.0, 1.0]]]])
        >>> rasterize_segments(seg, torch.tensor([[True]]), torch.ones(1, 1, 1), 3, 4)[0, 0]
        tensor([[0., 0., 0., 0.],
                [1., 1., 1., 1.],
                [0., 0., 0., 0.]])
    """
    KORNIA_CHECK(height > 0 and width > 0, f"map size must be positive, got {height}x{width}")
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(mask, ["B", "N"])
    KORNIA_CHECK_SHAPE(values, ["B", "N", "C"])
    B, N, C = values.shape
    area = height * width
    out = values.new_zeros(B, C, height, width)
    if N == 0 or C == 0 or not bool(mask.any()):
        return out
    seg, key = _segment_pixels(segments, mask, height, width)
    src = values.reshape(B * N, C).index_select(0, seg)  # (P, C)
    base = key + (seg // N) * ((C - 1) * area)  # position of channel 0 in out's (B, C, H, W) layout
    flat = out.view(-1)
    if torch.is_grad_enabled() and src.requires_grad:  # amax's backward needs its output: no in-place chunks
        chunk_channels = C
        flat = flat.clone()
    for c0 in range(0, C, chunk_channels):
        channel = torch.arange(c0, min(C, c0 + chunk_channels), device=values.device)
        index = base[:, None] + channel * area  # (P, c)
        flat = flat.scatter_reduce_(0, index.flatten(), src[:, c0 : c0 + len(channel)].flatten(), "amax")
    return flat.view(B, C, height, width)


def line_map_and_pooled_maps(
    segments: Tensor, mask: Tensor, values: Tensor, height: int, width: int, cell: int
) -> tuple[Tensor, Tensor]:
    """The line map (Eq. 13) at full resolution and, per channel of ``values``, the block means over ``cell`` x
    ``cell`` pixels of the maps :func:`rasterize_segments` draws, without drawing those: only the pixels the
    segments pass through are visited, so many channels at a coarse resolution cost little.

    Args:
        segments: (B, N, 2, 2) segment endpoints in the (full-resolution) map's pixels.
        mask: (B, N) bool, False for padding.
        values: (B, N, C) non-negative per-segment values.
        height: full map height, a multiple of ``cell``.
        width: full map width, a multiple of ``cell``.
        cell: side of the pooling cells in pixels.

    Returns:
        (B, 1, height, width) line map, equal to :func:`line_map`, and (B, C, height // cell, width // cell) pooled
        maps, equal to ``F.avg_pool2d(rasterize_segments(segments, mask, values, height, width), cell)``. The pooled
        maps are differentiable with respect to ``values``.

    Example:
        >>> seg = torch.tensor([[[[0.0, 1.0], [3.0, 1.0]]]])
        >>> lines, pooled = line_map_and_pooled_maps(seg, torch.tensor([[True]]), torch.ones(1, 1, 1), 4, 4, 2)
        >>> pooled[0, 0]
        tensor([[0.5000, 0.5000],
                [0.0000, 0.0000]])
    """
    KORNIA_CHECK(cell > 0 and height % cell == 0 and width % cell == 0, f"{height}x{width} is not a multiple of {cell}")
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(mask, ["B", "N"])
    KORNIA_CHECK_SHAPE(values, ["B", "N", "C"])
    drawn = drawn_pixels(segments, mask, height, width)
    return drawn.line_map, pooled_maps(drawn, values, cell)


class DrawnPixels(NamedTuple):
    """The pixels a batch of segments covers in a map (:func:`drawn_pixels`), kept to pool many channels of
    per-segment values over them later (:func:`pooled_maps`); what does not depend on the values.

    Attributes:
        line_map: (B, 1, H, W) the line map (Eq. 13).
        seg: (P,) for each (segment, pixel) pair, the segment's index in the flattened (B * N) segments.
        key: (P,) the pair's pixel, an index into the flattened (B, H, W) maps.
        pixels: (D,) the drawn pixels, sorted.
        num_segments: N, segments per image (padding included).
    """

    line_map: Tensor
    seg: Tensor
    key: Tensor
    pixels: Tensor
    num_segments: int


def drawn_pixels(segments: Tensor, mask: Tensor, height: int, width: int) -> DrawnPixels:
    """The line map (Eq. 13) of (B, N, 2, 2) segments in a ``height`` x ``width`` map's pixels, and the pixels they
    cover, for :func:`pooled_maps`."""
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(mask, ["B", "N"])
    B, N = mask.shape
    if N == 0 or not bool(mask.any()):
        none = torch.zeros(0, dtype=torch.long, device=segments.device)
        return DrawnPixels(segments.new_zeros(B, 1, height, width), none, none, none, N)
    seg, key = _segment_pixels(segments, mask, height, width)
    # a dense mark per pixel lists the drawn pixels in the order of their index (each cell sums its pixels in
    # that order), without sorting the pairs
    drawn = torch.zeros(B * height * width, dtype=torch.bool, device=key.device).index_fill_(0, key, True)
    lines = drawn.to(segments.dtype).view(B, 1, height, width)
    return DrawnPixels(lines, seg, key, drawn.nonzero().squeeze(1), N)


def pooled_maps(drawn: DrawnPixels, values: Tensor, cell: int) -> Tensor:
    """Per channel of the (B, N, C) per-segment ``values``, the block means over ``cell`` x ``cell`` pixels of the
    maps :func:`rasterize_segments` would draw over the pixels of ``drawn``: (B, C, H // cell, W // cell).
    Differentiable with respect to ``values``."""
    KORNIA_CHECK_SHAPE(values, ["B", "N", "C"])
    B, _, height, width = drawn.line_map.shape
    N, C = values.shape[1:]
    KORNIA_CHECK(cell > 0 and height % cell == 0 and width % cell == 0, f"{height}x{width} is not a multiple of {cell}")
    KORNIA_CHECK(
        values.shape[0] == B and N == drawn.num_segments, "values must have the drawn segments' batch and count"
    )
    rows, cols = height // cell, width // cell
    pooled = values.new_zeros(B * rows * cols, C)
    if len(drawn.key) > 0 and C > 0:
        seg, key, pixels = drawn.seg, drawn.key, drawn.pixels
        per_pixel = _pixel_max(values.reshape(B * N, C).contiguous(), seg, key, pixels, B * height * width)
        cells = _cell_index(B, height, width, cell, key.device).index_select(0, pixels)
        pooled = pooled.index_add(0, cells, per_pixel)
    return (pooled / (cell * cell)).view(B, rows, cols, C).permute(0, 3, 1, 2)


def _pixel_max(values: Tensor, seg: Tensor, key: Tensor, pixels: Tensor, size: int) -> Tensor:
    """(len(pixels), C) per drawn pixel the largest ``values`` (M, C) row of the segments through it, from the
    (segment, pixel) pairs ``seg``, ``key``; ``pixels``: the drawn pixels, sorted, of maps of ``size`` pixels."""
    # most pixels lie on one segment and take its values: the maximum is taken only where segments share a pixel
    owner = seg.new_zeros(size).index_copy_(0, key, seg)  # one of the segments through each pixel
    per_pixel = values.index_select(0, owner.index_select(0, pixels))
    others = (owner.index_select(0, key) != seg).nonzero().squeeze(1)  # the pairs of the other segments
    if len(others) == 0:
        return per_pixel
    rank = owner.index_put_((pixels,), torch.arange(len(pixels), device=pixels.device))  # each pixel's position
    which = rank.index_select(0, key.index_select(0, others))[:, None].expand(-1, values.shape[1])
    src = values.index_select(0, seg.index_select(0, others))
    if torch.is_grad_enabled() and per_pixel.requires_grad:  # amax's backward needs the untouched rows
        return per_pixel.scatter_reduce(0, which, src, "amax")
    return per_pixel.scatter_reduce_(0, which, src, "amax")


def _steps(counts: list[int], like: Tensor) -> Tensor:
    """(B, S) positions ``linspace(0, 1, counts[b])`` padded with 1 to the longest: padding repeats the last point."""
    if len(set(counts)) == 1:
        return torch.linspace(0.0, 1.0, counts[0], device=like.device, dtype=like.dtype).expand(len(counts), -1)
    t = like.new_ones(len(counts), max(counts))
    for b, n in enumerate(counts):
        t[b, :n] = torch.linspace(0.0, 1.0, n, device=like.device, dtype=like.dtype)
    return t


@lru_cache(maxsize=16)
def _cell_index(batch: int, height: int, width: int, cell: int, device: torch.device) -> Tensor:
    """(batch * height * width,) the index of the ``cell`` x ``cell`` cell (row-major, image after image) each pixel
    of a batch of maps falls in; an ordinary tensor even when first built in inference mode (cached, it may serve
    callers with autograd later)."""
    with torch.inference_mode(False):
        y, x = torch.arange(height, device=device) // cell, torch.arange(width, device=device) // cell
        index = (y[:, None] * (width // cell) + x).flatten()
        return (torch.arange(batch, device=device)[:, None] * ((height // cell) * (width // cell)) + index).flatten()


def _shortened(segments: Tensor, height: int, width: int) -> Tensor:
    """(..., 2, 2) segments with those longer than any segment inside the map can be cut to the map's rectangle
    (one pixel around it kept): they cover the same pixels of it, and the points sampled along them stay a few
    thousand, where a segment thrown far out (undistorted beyond the lens model's reach) would ask for billions.
    Segments no longer than that are returned as they are, so their pixels do not change."""
    limit = 2.0 * (height + width) + 4.0
    d = segments[..., 1, :] - segments[..., 0, :]
    long = torch.linalg.vector_norm(d, dim=-1) > limit
    if not bool(long.any()):
        return segments
    wide = torch.float32 if segments.device.type == "mps" else torch.float64  # MPS has no float64
    p, d = segments[..., 0, :].to(wide), d.to(wide)  # ends millions of pixels out: float32 would miss the map
    low, high = p.new_tensor([-1.0, -1.0]), p.new_tensor([width + 0.0, height + 0.0])
    d = torch.where(d == 0, torch.full_like(d, 1e-12), d)
    a, b = (low - p) / d, (high - p) / d  # where each coordinate crosses the rectangle's sides (Liang-Barsky)
    enter = torch.minimum(a, b).amax(-1).clamp(0.0, 1.0)
    leave = torch.maximum(a, b).amin(-1).clamp(0.0, 1.0).maximum(enter)  # a segment that misses it: one point
    cut = torch.stack([p + enter[..., None] * d, p + leave[..., None] * d], -2)
    return torch.where(long[..., None, None], cut.to(segments.dtype), segments)


def _segment_pixels(segments: Tensor, mask: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Every (segment, pixel) pair a drawn segment covers, once: the segment's index in the flattened (B * N)
    segments and the pixel's index in the flattened (B, H, W) maps, from points sampled about one pixel apart and
    rounded to the nearest pixel."""
    B, N = mask.shape
    segments = _shortened(segments.detach(), height, width)
    length = torch.linalg.vector_norm(segments[..., 1, :] - segments[..., 0, :], dim=-1)
    # sample points per image, by its own longest segment: an image's map does not depend on the rest of its batch
    longest = torch.where(mask, length, 0.0).amax(-1).ceil().long() + 2  # (B,)
    t = _steps(longest.tolist(), segments)  # (B, S)
    seg = mask.flatten().nonzero().squeeze(1)  # only the drawn segments are sampled
    image = seg // N
    ends = segments.detach().reshape(B * N, 4).index_select(0, seg)  # (M, 4): x0, y0, x1, y1
    steps = t if B == 1 else t.index_select(0, image)
    # x and y as separate (M, S) grids: the same arithmetic as on points, on contiguous rows
    x0, y0, x1, y1 = ends[:, :, None].unbind(1)
    x = torch.addcmul(x0, x1 - x0, steps).round_()
    y = torch.addcmul(y0, y1 - y0, steps).round_()
    # rounded coordinates are whole numbers below 2^24, so the flat index is exact; a row length of at least 2
    # keeps neighbouring samples apart
    row_length = max(width, 2)
    pixel = torch.add(x, y, alpha=row_length)  # (M, S)
    # along a straight segment both rounded coordinates are monotone and move at most one pixel a step, so a
    # pixel's samples are consecutive (padding repeats the last): keeping the first of each run gives every
    # (segment, pixel) once
    keep = torch.ones_like(pixel, dtype=torch.bool)
    torch.ne(pixel[:, 1:], pixel[:, :-1], out=keep[:, 1:])
    # the samples lie between the segment's first and last (monotone), so only segments with an end outside the
    # map need a test per sample
    last = t.shape[1] - 1
    outside = _outside(torch.stack([x[:, ::last], y[:, ::last]], -1), height, width).any(-1)
    if bool(outside.any()):
        keep[outside] &= ~_outside(torch.stack([x[outside], y[outside]], -1), height, width)
    flat = keep.flatten().nonzero().squeeze(1)
    row = flat // t.shape[1]
    key = pixel.flatten().index_select(0, flat).long()
    if row_length != width:  # a single column: x is 0
        key = key // row_length
    if B > 1:
        key = key + image.index_select(0, row) * (height * width)
    return seg.index_select(0, row), key


def _outside(xy: Tensor, height: int, width: int) -> Tensor:
    """(..., 2) rounded pixel coordinates -> (...) bool: outside a ``height`` x ``width`` map."""
    # whole numbers: inside iff within half the map's size (less one) of its middle
    half = image_center(height, width, like=xy)
    return ((xy - half).abs_() > half).any(-1)


def line_map(segments: Tensor, mask: Tensor, height: int, width: int) -> Tensor:
    """Binary line-segment map L of Eq. 13: (B, N, 2, 2) -> (B, 1, H, W).

    Example:
        >>> seg = torch.tensor([[[[1.0, 0.0], [1.0, 2.0]]]])
        >>> line_map(seg, torch.tensor([[True]]), 3, 3)[0, 0]
        tensor([[0., 1., 0.],
                [0., 1., 0.],
                [0., 1., 0.]])
    """
    ones = segments.new_ones(*segments.shape[:2], 1)
    return rasterize_segments(segments, mask, ones, height, width)


def closeness_maps(segments: Tensor, mask: Tensor, closeness: Tensor, height: int, width: int) -> Tensor:
    """Closeness maps A_x, A_y, A_z of Eq. 15, one per VP of a frame.

    Args:
        segments: (B, N, 2, 2) segments in the map's pixels.
        mask: (B, N) bool.
        closeness: (B, 3, N) closeness of every segment to each of the frame's three VPs (Eq. 14, or a sharper
            kernel).
        height: map height.
        width: map width.

    Returns:
        (B, 3, H, W) maps.
    """
    KORNIA_CHECK_SHAPE(closeness, ["B", "3", "N"])
    return rasterize_segments(segments, mask, closeness.transpose(1, 2), height, width)


def manhattan_score_maps(line_map: Tensor, closeness_maps: Tensor) -> Tensor:
    r"""Manhattan score of Eq. 21 on rasterised maps, :math:`\sum \max(A_x, A_y, A_z) / \sum L`.

    Args:
        line_map: (B, 1, H, W) binary line map.
        closeness_maps: (B, 3, H, W) closeness maps.

    Returns:
        (B,) scores; 0 for an empty line map.

    Example:
        >>> L = torch.ones(1, 1, 2, 2)
        >>> A = torch.zeros(1, 3, 2, 2); A[0, 1] = 0.5
        >>> manhattan_score_maps(L, A)
        tensor([0.5000])
    """
    KORNIA_CHECK_SHAPE(line_map, ["B", "1", "H", "W"])
    KORNIA_CHECK_SHAPE(closeness_maps, ["B", "3", "H", "W"])
    num = closeness_maps.amax(1).flatten(1).sum(-1)
    return num / line_map.flatten(1).sum(-1).clamp_min(1.0)
