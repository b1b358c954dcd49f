r"""Rasterised line maps (Eq. 13), closeness maps (Eq. 15) and the map form of the Manhattan score (Eq. 21).

Segments are drawn by sampling points about one pixel apart along each segment and writing each segment's
value into the nearest pixel; where segments overlap a pixel keeps the largest value. The maps are
differentiable with respect to the per-segment values (so closeness maps pass gradients to the VPs).
"""

from __future__ import annotations

import torch
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor

__all__ = ["line_map", "closeness_maps", "manhattan_score_maps", "line_map_and_pooled_maps", "rasterize_segments"]


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
    b, n, pix = _segment_pixels(segments, mask, height, width)
    src = values[b, n]  # (P, C)
    base = b * (C * area) + pix  # position of channel 0 in out's (B, C, H, W) layout
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
    B, N, C = values.shape
    area, rows, cols = height * width, height // cell, width // cell
    lines = values.new_zeros(B * area)
    pooled = values.new_zeros(B * rows * cols, C)
    if N > 0 and C > 0 and bool(mask.any()):
        b, n, pix = _segment_pixels(segments, mask, height, width)
        # where segments overlap, a pixel keeps the largest value (as drawn), then each cell sums its pixels
        pixels, which = torch.unique(b * area + pix, return_inverse=True)
        lines[pixels] = 1.0
        per_pixel = values.new_zeros(len(pixels), C).scatter_reduce(
            0, which[:, None].expand(-1, C), values[b, n], "amax"
        )
        image, pix = pixels // area, pixels % area
        pooled = pooled.index_add(0, (image * rows + pix // width // cell) * cols + pix % width // cell, per_pixel)
    pooled = (pooled / (cell * cell)).view(B, rows, cols, C).permute(0, 3, 1, 2)
    return lines.view(B, 1, height, width), pooled


def _steps(counts: list[int], like: Tensor) -> tuple[Tensor, Tensor]:
    """(B, S) positions ``linspace(0, 1, counts[b])`` padded to the longest, and (B, S) bool: which are real."""
    size = max(counts)
    t = like.new_zeros(len(counts), size)
    for b, n in enumerate(counts):
        t[b, :n] = torch.linspace(0.0, 1.0, n, device=like.device, dtype=like.dtype)
    sampled = torch.arange(size, device=like.device) < torch.tensor(counts, device=like.device)[:, None]
    return t, sampled


def _segment_pixels(segments: Tensor, mask: Tensor, height: int, width: int) -> tuple[Tensor, Tensor, Tensor]:
    """Every (segment, pixel) pair a drawn segment covers, once: image index, segment index and flat pixel index
    (``y * width + x``), from points sampled about one pixel apart and rounded to the nearest pixel."""
    length = (segments[..., 1, :] - segments[..., 0, :]).norm(dim=-1).detach()
    # sample points per image, by its own longest segment: an image's map does not depend on the rest of its batch
    longest = torch.where(mask, length, torch.zeros_like(length)).amax(-1).ceil().long() + 2  # (B,)
    t, sampled = _steps(longest.tolist(), segments)  # (B, S)
    p0, p1 = segments[..., 0, :].detach(), segments[..., 1, :].detach()
    ij = (p0[:, :, None] + (p1 - p0)[:, :, None] * t[:, None, :, None]).round().long()  # (B, N, S, 2)
    inside = (ij[..., 0] >= 0) & (ij[..., 0] < width) & (ij[..., 1] >= 0) & (ij[..., 1] < height)
    inside &= mask[:, :, None] & sampled[:, None]
    # along a straight segment both rounded coordinates are monotone, so a pixel's samples are consecutive: keeping
    # the first of each run gives every (segment, pixel) once, without sorting all the samples
    inside[..., 1:] &= (ij[..., 1:, :] != ij[..., :-1, :]).any(-1)
    pixel = ij[..., 1] * width + ij[..., 0]
    b, n, s = inside.nonzero(as_tuple=True)
    return b, n, pixel[b, n, s]


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
