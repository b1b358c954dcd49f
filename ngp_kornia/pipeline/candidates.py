"""Candidate sampling of Sec. 3.1-3.2 and Fig. 3: zenith candidates, horizontal line groups, horizontal VP
candidates and Manhattan-frame candidates.

Everything works in the pseudo camera (:func:`ngp_kornia.geometry.to_pseudo_camera`): the image centre is the
origin and one unit is half the image's long side, so a focal length ``f`` here is ``f * max(H, W) / 2`` pixels.
Sampling is random, batched and reproducible through a ``torch.Generator``; variable counts are padded and masked.
Every ``generator`` argument also takes a sequence of B generators, one per image: each image then draws from its
own stream, and its candidates do not depend on the other images of the batch or on its position in it (the parser
gives every image a generator seeded with the same seed, so an image gets in a batch the answer it gets alone).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.geometry import (
    intersect_lines,
    is_near_vertical,
    normalize,
    segment_vp_angle,
)
from ngp_kornia.geometry.frames import FrameCandidates, frames_from_vps
from ngp_kornia.geometry.vp import true_positions

#: ``torch.cdist`` switches to its matrix-product expansion when either point set is larger than this
_CDIST_MM_ABOVE = 25

#: a random generator, or one per image of the batch
Generators = torch.Generator | Sequence[torch.Generator] | None

__all__ = [
    "Generators",
    "sample_horizontal_pair_frames",
    "horizontal_line_mask",
    "nearest_vertical_endpoint",
    "sample_frames",
    "sample_horizontal_vps",
    "sample_candidate_frames",
    "sample_pairs",
    "sample_zenith_candidates",
    "split_by_pseudo_horizon",
]


def sample_pairs(
    weights: Tensor, count: int, generator: Generators = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Draw ``count`` random pairs of distinct items per row, each item with probability proportional to its weight.

    Args:
        weights: (B, N) non-negative weights; zero for items that must not be drawn.
        count: pairs per row.
        generator: random generator for reproducibility, or one per row.

    Returns:
        first (B, count) and second (B, count) long indices and valid (B, count) bool; a pair is invalid when its
        row has fewer than two drawable items or both draws hit the same item.

    Example:
        >>> i, j, ok = sample_pairs(torch.tensor([[1.0, 1.0, 0.0]]), 4, torch.Generator().manual_seed(0))
        >>> bool(((i < 2) & (j < 2)).all()), bool((ok == (i != j)).all())
        (True, True)
    """
    KORNIA_CHECK_SHAPE(weights, ["B", "N"])
    usable, (draws,) = _pair_draws(weights, (count,), generator)
    first, second = draws[:, :count], draws[:, count:]
    return first, second, usable & (first != second)


def _pair_draws(weights: Tensor, counts: Sequence[int], generator: Generators) -> tuple[Tensor, list[Tensor]]:
    """The draws of :func:`sample_pairs` for each of ``counts`` in turn, from the same (B, N) weights: (B, 1) bool
    rows with two drawable items and, per count c, (B, 2c) indices (the first items, then the second ones)."""
    B, N = weights.shape
    usable = (weights > 0).sum(-1, keepdim=True) >= 2
    if N == 0:
        return usable, [torch.zeros(B, 2 * c, dtype=torch.long, device=weights.device) for c in counts]
    w = torch.where(usable, weights.clamp_min(0), 1.0).float().cpu()
    return usable, [_multinomial(w, 2 * c, generator).to(weights.device) for c in counts]


def _multinomial(weights: Tensor, count: int, generator: Generators) -> Tensor:
    """``count`` draws with replacement per row of (B, N) ``weights``; with one generator per row, row b uses only
    ``generator[b]``."""
    if generator is None or isinstance(generator, torch.Generator):
        return torch.multinomial(weights, count, replacement=True, generator=generator)
    generators = list(generator)
    if len(generators) != len(weights):
        raise ValueError(f"got {len(generators)} generators for a batch of {len(weights)}; give one per image")
    if len(generators) == 1:  # one image: its row is the whole tensor, no split needed
        return torch.multinomial(weights, count, replacement=True, generator=generators[0])
    pairs = zip(weights.split(1), generators, strict=True)
    rows = [torch.multinomial(w, count, replacement=True, generator=g) for w, g in pairs]
    if len(rows) <= 1:  # a single image needs no concatenation
        return rows[0] if rows else weights.new_zeros(0, count, dtype=torch.long)
    return torch.cat(rows)


def _gather(x: Tensor, index: Tensor) -> Tensor:
    if x.shape[1] == 0:  # nothing to draw from: finite zeros, masked invalid by the caller
        return x.new_zeros(*index.shape, x.shape[-1])
    return torch.gather(x, 1, index[..., None].expand(*index.shape, x.shape[-1]))


def sample_zenith_candidates(
    lines: Tensor,
    lengths: Tensor,
    mask: Tensor,
    num_lines: int = 256,
    num_candidates: int = 256,
    threshold_deg: float = 67.5,
    generator: Generators = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Near-vertical lines L_z (Eq. 4) and zenith candidates Z from random pairs of them (Eq. 3).

    Lines are drawn with probability proportional to their length.

    Args:
        lines: (B, N, 3) homogeneous lines.
        lengths: (B, N) segment lengths.
        mask: (B, N) bool, False for padding.
        num_lines: |L_z|.
        num_candidates: |Z|.
        threshold_deg: delta_z of Eq. 4.
        generator: random generator, or one per image.

    Returns:
        L_z (B, num_lines, 3), its mask (B, num_lines), Z (B, num_candidates, 3) unit homogeneous points and
        their mask (B, num_candidates). Masks are all False for an image without two near-vertical lines.
    """
    KORNIA_CHECK_SHAPE(lines, ["B", "N", "3"])
    vertical = mask & is_near_vertical(lines, threshold_deg)
    usable, (idx, pairs) = _pair_draws(lengths * vertical.to(lengths), (num_lines, num_candidates), generator)
    line_mask = (vertical.sum(-1, keepdim=True) >= 2).expand(-1, num_lines)
    ends = _gather(lines, pairs)  # both lines of every pair in one gather
    zenith = intersect_lines(ends[:, :num_candidates], ends[:, num_candidates:])
    ok = usable & (pairs[:, :num_candidates] != pairs[:, num_candidates:])
    ok = ok & (torch.linalg.vector_norm(zenith, dim=-1) > 0.5)  # identical lines have no intersection
    return _gather(lines, idx[:, :num_lines]), line_mask, zenith, ok


def horizontal_line_mask(
    segments: Tensor,
    mask: Tensor,
    zenith: Tensor,
    vertical_tol_deg: float = 5.0,
    junction_radius: float = 0.03,
    min_lines: int = 8,
) -> Tensor:
    """The junction filter of Fig. 3 (a-c): lines that do not point at the zenith and have an endpoint near an
    endpoint of a line that does (corners of facades, windows, doors).

    Falls back to every non-vertical line when fewer than ``min_lines`` pass the filter.

    Args:
        segments: (B, N, 2, 2) segments in pseudo-camera units.
        mask: (B, N) bool.
        zenith: (B, 3) zenith estimate in pseudo-camera units.
        vertical_tol_deg: a line within this angle of the ray to the zenith counts as vertical.
        junction_radius: endpoint distance (pseudo-camera units; 0.03 is 1.5% of the long side) for a junction.
        min_lines: fall-back threshold.

    Returns:
        (B, N) bool mask of horizontal-direction lines.
    """
    KORNIA_CHECK_SHAPE(segments, ["B", "N", "2", "2"])
    KORNIA_CHECK_SHAPE(zenith, ["B", "3"])
    angle = segment_vp_angle(segments, zenith[:, None])[:, 0]
    vertical = mask & (angle < vertical_tol_deg)
    other = mask & ~vertical
    at_junction = nearest_vertical_endpoint(segments, vertical) < junction_radius
    selected = other & at_junction.reshape(*mask.shape, 2).any(-1)
    enough = selected.sum(-1, keepdim=True) >= min_lines
    return torch.where(enough, selected, other)


def nearest_vertical_endpoint(segments: Tensor, vertical: Tensor) -> Tensor:
    """Distance from every endpoint (B, N, 2, 2) to the nearest endpoint of a ``vertical`` (B, N) line: (B, 2N),
    infinite without one. The values of ``torch.cdist``'s minimum, computed from the endpoints of the vertical
    lines only, which are few, and square-rooting only the minima."""
    counts = vertical.sum(-1)
    count = int(counts.max()) if vertical.numel() else 0
    ends = segments.flatten(1, 2)  # (B, 2N, 2)
    if count == 0:
        return ends.new_full(ends.shape[:2], float("inf"))
    order = true_positions(vertical, count)  # the vertical lines
    vert_ends = _gather(segments.flatten(2), order).reshape(len(order), 2 * count, 2)  # (B, 2V, 2)
    small = ends.shape[1] <= _CDIST_MM_ABOVE and vert_ends.shape[1] <= _CDIST_MM_ABOVE
    if small:  # cdist subtracts directly at this size: use its distances
        dist = torch.cdist(ends, vert_ends)
    else:  # cdist's matrix-product expansion, |x|^2 - 2 x.y + |y|^2, before its clamp and square root
        x_sq, y_sq = ends.square().sum(-1, keepdim=True), vert_ends.square().sum(-1, keepdim=True)
        x = torch.cat([ends * -2, x_sq, torch.ones_like(x_sq)], -1)
        y = torch.cat([vert_ends, torch.ones_like(y_sq), y_sq], -1)
        dist = x @ y.transpose(-1, -2)  # (B, 2N, 2V) squared distances
    if not bool((counts == count).all()):  # padding of images with fewer vertical lines than the batch's most
        vert_ok = _gather(vertical[..., None], order)[..., 0].repeat_interleave(2, 1)  # (B, 2V)
        dist = dist.masked_fill(~vert_ok[:, None, :], float("inf"))
    # the clamp and the square root are monotonic: applied to the minima only, they give the same values
    return dist.amin(-1) if small else dist.amin(-1).clamp_min_(0.0).sqrt_()


def split_by_pseudo_horizon(lines: Tensor, zenith: Tensor) -> Tensor:
    """Fig. 3 (d): which side of the pivot (the line through the zenith and the image centre) each line crosses
    the pseudo-horizon on.

    In the pseudo camera ``K_p = I``, so the pseudo-horizon of a zenith ``z`` is the line ``z`` itself.

    Args:
        lines: (B, N, 3) lines in pseudo-camera units.
        zenith: (B, 3) zenith in pseudo-camera units.

    Returns:
        (B, N) bool, True for the right-hand group (lines parallel to the horizon count as right).
    """
    KORNIA_CHECK_SHAPE(lines, ["B", "N", "3"])
    horizon = normalize(zenith)
    centre = torch.zeros_like(horizon)
    centre[:, 2] = 1.0
    pivot_point = torch.linalg.cross(torch.linalg.cross(horizon, centre), horizon)  # (B, 3)
    direction = torch.stack([horizon[:, 1], -horizon[:, 0]], -1)
    direction = direction * torch.where(direction[:, :1] < 0, -1.0, 1.0).to(direction)  # left to right
    crossing = torch.linalg.cross(lines, horizon[:, None].expand_as(lines))  # (B, N, 3)
    # sign of (crossing/w_c - pivot/w_p) . direction without dividing by w
    diff = crossing[..., :2] * pivot_point[:, None, 2:] - pivot_point[:, None, :2] * crossing[..., 2:]
    side = (diff * direction[:, None]).sum(-1) * crossing[..., 2] * pivot_point[:, None, 2]
    return side >= 0


def sample_horizontal_vps(
    lines: Tensor,
    lengths: Tensor,
    horizontal: Tensor,
    right: Tensor,
    count: int = 256,
    generator: Generators = None,
) -> tuple[Tensor, Tensor]:
    """Horizontal VP candidates: intersections of random pairs within each group, ``count // 2`` per group.

    Args:
        lines: (B, N, 3) lines.
        lengths: (B, N) segment lengths (sampling weights).
        horizontal: (B, N) bool mask of horizontal-direction lines.
        right: (B, N) bool group of each line (:func:`split_by_pseudo_horizon`).
        count: number of candidates.
        generator: random generator, or one per image.

    Returns:
        (B, 2 * (count // 2), 3) unit homogeneous VPs, the right-hand group first, and their mask.
    """
    half = count // 2
    draws, valid = [], []
    for group in (horizontal & right, horizontal & ~right):
        usable, (pairs,) = _pair_draws(lengths * group.to(lengths), (half,), generator)
        draws.append(pairs)
        valid.append(usable & (pairs[:, :half] != pairs[:, half:]))
    # both groups' first lines, then both groups' second lines, in one gather and one intersection
    ends = _gather(lines, torch.cat([d[:, :half] for d in draws] + [d[:, half:] for d in draws], 1))
    vps = intersect_lines(ends[:, : 2 * half], ends[:, 2 * half :])
    return vps, torch.cat(valid, 1) & (torch.linalg.vector_norm(vps, dim=-1) > 0.5)


def sample_frames(
    zenith: Tensor,
    zenith_weights: Tensor,
    horizontal: Tensor,
    horizontal_mask: Tensor,
    count: int = 1024,
    focal_range: tuple[float, float] = (0.8, 4.0),
    generator: Generators = None,
    focal: float | Tensor | None = None,
) -> FrameCandidates:
    """Manhattan-frame candidates: each pairs a zenith drawn by its weight (ZSNet score, or uniform over Z_c) with a
    uniformly drawn horizontal VP.

    Args:
        zenith: (B, Z, 3) zenith candidates.
        zenith_weights: (B, Z) non-negative weights, zero outside Z_c.
        horizontal: (B, H, 3) horizontal VP candidates.
        horizontal_mask: (B, H) bool.
        count: number of frames F.
        focal_range: see :func:`frames_from_vps`.
        generator: random generator, or one per image.
        focal: a known focal length (pseudo-camera units), one for all or (B,), see :func:`frames_from_vps`.

    Returns:
        :class:`FrameCandidates` with F = ``count``.
    """
    KORNIA_CHECK_SHAPE(zenith_weights, ["B", "Z"])
    KORNIA_CHECK_SHAPE(horizontal_mask, ["B", "H"])
    first, second, ok = _zenith_pairs(zenith, zenith_weights, horizontal, horizontal_mask, count, generator)
    return frames_from_vps(first, second, ok, focal_range, focal)


def _zenith_pairs(
    zenith: Tensor,
    zenith_weights: Tensor,
    horizontal: Tensor,
    horizontal_mask: Tensor,
    count: int,
    generator: Generators,
) -> tuple[Tensor, Tensor, Tensor]:
    """The draws of :func:`sample_frames`: zeniths (B, count, 3), horizontal VPs (B, count, 3), validity."""
    zi, zok = _draw(zenith_weights, count, generator)
    hi, hok = _draw(horizontal_mask.to(zenith_weights), count, generator)
    return _gather(zenith, zi), _gather(horizontal, hi), zok & hok


def _draw(  # one weighted draw per frame, with replacement
    weights: Tensor, count: int, generator: Generators
) -> tuple[Tensor, Tensor]:
    if weights.shape[1] == 0:
        idx = torch.zeros(weights.shape[0], count, dtype=torch.long, device=weights.device)
        return idx, torch.zeros_like(idx, dtype=torch.bool)
    usable = (weights > 0).any(-1, keepdim=True)
    w = torch.where(usable, weights.clamp_min(0), torch.ones_like(weights)).float()
    idx = _multinomial(w.cpu(), count, generator).to(weights.device)
    return idx, usable & (torch.gather(weights, 1, idx) > 0)


def sample_horizontal_pair_frames(
    horizontal: Tensor,
    horizontal_mask: Tensor,
    count: int = 512,
    focal_range: tuple[float, float] = (0.8, 4.0),
    generator: Generators = None,
    focal: float | Tensor | None = None,
) -> FrameCandidates:
    """Manhattan-frame candidates from two horizontal VPs, one from each group of :func:`sample_horizontal_vps`
    (its first half is the right-hand group, its second half the left-hand one).

    These frames get their focal length from the two horizontal VPs, so they stay accurate for a level camera, whose
    zenith is at infinity.

    Args:
        horizontal: (B, H, 3) horizontal VP candidates, right-hand group first.
        horizontal_mask: (B, H) bool.
        count: number of frames.
        focal_range: see :func:`frames_from_vps`.
        generator: random generator, or one per image.
        focal: a known focal length (pseudo-camera units), one for all or (B,), see :func:`frames_from_vps`.

    Returns:
        :class:`FrameCandidates` with F = ``count``.
    """
    KORNIA_CHECK_SHAPE(horizontal_mask, ["B", "H"])
    return frames_from_vps(*_horizontal_pairs(horizontal, horizontal_mask, count, generator), focal_range, focal)


def _horizontal_pairs(
    horizontal: Tensor, horizontal_mask: Tensor, count: int, generator: Generators
) -> tuple[Tensor, Tensor, Tensor]:
    """The draws of :func:`sample_horizontal_pair_frames`: right-hand VPs (B, count, 3), left-hand VPs, validity."""
    half = horizontal.shape[1] // 2
    weights = horizontal_mask.to(horizontal)
    ri, rok = _draw(weights[:, :half], count, generator)
    li, lok = _draw(weights[:, half:], count, generator)
    return _gather(horizontal[:, :half], ri), _gather(horizontal[:, half:], li), rok & lok


def sample_candidate_frames(
    zenith: Tensor,
    zenith_weights: Tensor,
    horizontal: Tensor,
    horizontal_mask: Tensor,
    count: int = 1024,
    pair_count: int = 512,
    focal_range: tuple[float, float] = (0.8, 4.0),
    generator: Generators = None,
    focal: float | Tensor | None = None,
) -> FrameCandidates:
    """The parser's frame candidates: ``cat_frames(sample_frames(..., count, ...),
    sample_horizontal_pair_frames(..., pair_count, ...))``, the same draws in the same order, with all the frames
    built in one pass (fewer operations). Each frame depends on its own pair alone, so the frames are the same
    (for counts that are not multiples of PyTorch's vector width, a focal length may differ in the last bit where
    its square root moves between the vectorised loop and the scalar tail).

    Args:
        zenith, zenith_weights, horizontal, horizontal_mask: see :func:`sample_frames`.
        count: frames from a zenith and a horizontal VP.
        pair_count: frames from two horizontal VPs (none when 0).
        focal_range, generator, focal: see :func:`sample_frames`.

    Returns:
        :class:`FrameCandidates` with F = ``count + pair_count``, the zenith-horizontal frames first.
    """
    KORNIA_CHECK_SHAPE(zenith_weights, ["B", "Z"])
    KORNIA_CHECK_SHAPE(horizontal_mask, ["B", "H"])
    first, second, ok = _zenith_pairs(zenith, zenith_weights, horizontal, horizontal_mask, count, generator)
    if pair_count > 0:
        pairs = _horizontal_pairs(horizontal, horizontal_mask, pair_count, generator)
        first, second, ok = (torch.cat(both, 1) for both in zip((first, second, ok), pairs, strict=True))
    return frames_from_vps(first, second, ok, focal_range, focal)
