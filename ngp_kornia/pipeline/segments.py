"""Line-segment detection with OpenCV's LSD, returned as padded torch tensors.

:func:`detect_segments` is the one entry point: every caller (the parser, :func:`ngp_kornia.calibrate`, folder
prediction, the CLI overlay, the training cache, the benchmarks) gets its segments from it, with the settings of a
:class:`~ngp_kornia.pipeline.settings.SegmentSettings`, so all of them see the same lines for the same image.

LSD runs on the 8-bit greyscale image resized so its long side is at most ``working_size`` (aspect ratio kept); the
segments are mapped back to the input's pixels (pixel-centre convention), filtered by length and padded to
``(B, N, 2, 2)`` with a ``(B, N)`` mask.

LSD runs on ``line_strips`` (default 2) horizontal strips of the image at once, one thread each as far as the process
has cores (at most :func:`line_workers`), and a line cut between two strips is joined again: on two idle cores that
takes 0.6x the time of one LSD over the whole image. The segments are not quite the whole image's (LSD's region
growing and its significance test depend on the image it sees): 94% of their length on York Urban and 98% on the
Eurasian Cities photos comes back within a pixel. They depend on ``line_strips`` only, never on the threads.

``SegmentSettings(detector="fld")`` uses OpenCV's FastLineDetector (opencv-contrib's ximgproc) instead: faster, and less
accurate on real photos (see BENCHMARKS.md).
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.io import read_rgb
from ngp_kornia.pipeline.settings import DETECTORS, SegmentSettings
from ngp_kornia.threads import usable_cores

__all__ = [
    "DETECTORS",
    "LineDetector",
    "detect_segments",
    "detect_segments_gray",
    "longest_segments",
    "line_workers",
    "pad_segments",
    "strip_threads",
]

_local = threading.local()


def _lsd() -> cv2.LineSegmentDetector:
    # one detector per thread: creating it costs more than detecting on a small image
    if not hasattr(_local, "lsd"):
        _local.lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
    return _local.lsd


def _fld(min_length: float):
    # OpenCV's defaults with the length limit built in: FastLineDetector otherwise returns thousands of tiny
    # fragments (about 7x as many segments as LSD on York Urban), which cost more time than the detection saves
    length = max(1, int(math.ceil(min_length)))
    detectors = _local.__dict__.setdefault("fld", {})
    if length not in detectors:
        ximgproc = getattr(cv2, "ximgproc", None)
        if ximgproc is None:
            raise ValueError("detector='fld' needs OpenCV's contrib modules (opencv-contrib-python-headless)")
        detectors[length] = ximgproc.createFastLineDetector(length)
    return detectors[length]


def detect_segments_gray(
    gray: np.ndarray, settings: SegmentSettings | None = None, meanwhile: Callable[[], object] | None = None
) -> np.ndarray:
    """Detect segments on one greyscale uint8 image: the LSD step of :func:`detect_segments`.

    Args:
        gray: (H, W) uint8 image.
        settings: LSD runs on a copy whose long side is at most ``working_size`` pixels, segments shorter than
            ``min_length`` (working-resolution pixels) are dropped and at most ``max_segments`` kept, the longest
            first, found by ``detector``, LSD in ``line_strips`` strips; None for the defaults.
        meanwhile: a job called once: by this thread when its own strip is done and another thread's may still
            run (the time it would wait), else after the detection. Its result is not kept.

    Returns:
        (N, 2, 2) float32 segments ``[[x0, y0], [x1, y1]]`` in the input's pixels, longest first.
    """
    s = SegmentSettings() if settings is None else settings
    working_size, min_length, max_segments, detector, strips = (
        s.working_size, s.min_length, s.max_segments, s.detector, s.line_strips
    )
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) uint8 greyscale image, got shape {gray.shape} dtype {gray.dtype}")
    h, w = gray.shape
    scale = min(1.0, working_size / max(h, w))
    small = (
        gray if scale == 1.0 else cv2.resize(gray, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    )
    gap = _once(meanwhile)
    seg = _lsd_in_strips(small, strips, gap) if detector == "lsd" else _as_segments(_fld(min_length).detect(small))
    gap()  # where no strip ran beside this thread
    if len(seg) == 0:
        return np.zeros((0, 2, 2), np.float32)
    seg = longest_segments(seg, min_length, max_segments)
    sx, sy = w / small.shape[1], h / small.shape[0]
    seg[..., 0] = (seg[..., 0] + 0.5) * sx - 0.5
    seg[..., 1] = (seg[..., 1] + 0.5) * sy - 0.5
    return seg


def _once(job: Callable[[], object] | None) -> Callable[[], None]:
    """A function that calls ``job`` the first time it is called, and does nothing after (nor ever for None)."""
    pending = [] if job is None else [job]

    def run() -> None:
        while pending:
            pending.pop()()

    return run


#: rows a strip reads beyond each of its cuts, so that LSD's smoothing and gradients near a cut see both sides
STRIP_OVERLAP = 10
#: LSD first resamples the image by 0.8: strips that start at multiples of 5 rows keep the whole image's samples
_GRID = 5
#: a line's pieces on both sides of a cut are joined when their directions differ by at most this (degrees) and
#: the lower piece's point on the cut lies within _JOIN_GAP pixels of the upper piece's line
_JOIN_ANGLE, _JOIN_GAP = 2.0, 1.5
#: the most threads a call's strips run on (None: the process's cores), set by :func:`line_workers`
_cap: int | None = None
#: the strips' pools, one per process (a pool's threads do not survive a fork)
_pools: dict[int, ThreadPoolExecutor] = {}


@contextmanager
def line_workers(count: int | None) -> Iterator[None]:
    """Let LSD's strips run on at most ``count`` threads inside the block, the caller's own included (None: as many
    as the process's cores). ``ngp predict`` gives each of its processes its share of the cores this way; the
    segments do not change."""
    global _cap
    saved, _cap = _cap, count
    try:
        yield
    finally:
        _cap = saved


def strip_threads(strips: int) -> int:
    """How many threads ``strips`` strips run on: at least 1, at most the process's cores (or :func:`line_workers`)."""
    return max(1, min(strips, usable_cores() if _cap is None else _cap))


def _pool() -> ThreadPoolExecutor:
    pid = os.getpid()
    if pid not in _pools:
        _pools[pid] = ThreadPoolExecutor(max_workers=max(1, usable_cores() - 1), thread_name_prefix="ngp-lsd")
    return _pools[pid]


def _detect_each(views: list[np.ndarray]) -> list[np.ndarray]:
    return [_lsd_segments(v) for v in views]


def _as_segments(found: np.ndarray | None) -> np.ndarray:
    # OpenCV 4 gives (N, 1, 4), OpenCV 5 (N, 4), and None when there is nothing
    return np.zeros((0, 2, 2), np.float32) if found is None else found.reshape(-1, 2, 2).astype(np.float32)


def _lsd_segments(image: np.ndarray) -> np.ndarray:
    return _as_segments(_lsd().detect(image)[0])


def _strip_cuts(height: int, strips: int) -> list[int]:
    """Rows between strips: evenly spaced, on the resampling grid, each strip at least 4 overlaps high."""
    cuts = sorted({round(height * i / strips / _GRID) * _GRID for i in range(1, strips)})
    if any(b - a < 4 * STRIP_OVERLAP for a, b in pairwise([0, *cuts, height])):
        return [] if strips <= 2 else _strip_cuts(height, strips - 1)
    return cuts


def _lsd_in_strips(image: np.ndarray, strips: int, gap: Callable[[], object] = lambda: None) -> np.ndarray:
    """LSD on ``strips`` horizontal strips of the image (:data:`STRIP_OVERLAP` rows beyond each cut), run at once
    on up to :func:`strip_threads` threads (OpenCV releases the GIL); every segment is clipped
    to its strip's rows and a line's pieces on both sides of a cut joined again. (N, 2, 2). ``gap`` runs when this
    thread's strips are done, before it waits for the others'."""
    cuts = _strip_cuts(image.shape[0], strips)
    if not cuts:
        return _lsd_segments(image)
    starts = [0] + [c - STRIP_OVERLAP for c in cuts]
    views = [image[a : b + STRIP_OVERLAP] for a, b in zip(starts, [*cuts, image.shape[0]], strict=True)]
    threads = strip_threads(len(views))
    parts: list = [None] * len(views)
    groups = [views[i::threads] for i in range(threads)]  # every thread-th strip: this thread takes the first group
    pending = [_pool().submit(_detect_each, group) for group in groups[1:]]
    first = _detect_each(groups[0])
    gap()  # the other strips end about a millisecond later on average
    # a group no pool thread has started by now (the pool busy with another call's strips) is detected here
    rest = [_detect_each(g) if p.cancel() else p.result() for g, p in zip(groups[1:], pending, strict=True)]
    for i, found in enumerate([first, *rest]):
        parts[i::threads] = found
    bands = pairwise([-math.inf, *cuts, math.inf])
    found = None
    for start, (low, high), seg in zip(starts, bands, parts, strict=True):
        seg[..., 1] += start
        seg = _clip_rows(seg, low, high)
        found = seg if found is None else _join_at_cut(found, seg, low)
    return found


def _clip_rows(seg: np.ndarray, low: float, high: float) -> np.ndarray:
    """The parts of segments within rows ``low < y <= high`` (a segment lying on ``low`` belongs to the strip above),
    ends moved onto the band's edge exactly; in their order."""
    # each segment's top and bottom row from its two ends (a reduction over the pair is several times slower)
    top, bottom = np.minimum(seg[:, 0, 1], seg[:, 1, 1]), np.maximum(seg[:, 0, 1], seg[:, 1, 1])
    near = (bottom > low) & (top <= high)
    seg = seg[near]
    cut = (top[near] <= low) | (bottom[near] > high)  # most segments lie inside and stay as they are
    if not cut.any():
        return seg
    part, kept = _clip_part(seg[cut].astype(np.float64), low, high)
    seg[cut] = part  # seg is already a copy (boolean indexing)
    keep = np.ones(len(seg), bool)
    keep[cut] = kept
    return seg[keep]


def _clip_part(seg: np.ndarray, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_clip_rows` of segments that reach its band (float64): the clipped segments and which are not empty."""
    y = seg[..., 1]
    dy = y[:, 1] - y[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low, t_high = (low - y[:, 0]) / dy, (high - y[:, 0]) / dy
    flat = dy == 0  # inside the band (kept above), so the whole segment
    t = np.stack([np.minimum(t_low, t_high), np.maximum(t_low, t_high)], 1).clip(0.0, 1.0)
    t = np.where(flat[:, None], (0.0, 1.0), t)  # (N, 2): where each clipped end lies on the segment
    t_in, t_out = t[:, 0], t[:, 1]
    out = seg[:, :1] + t[..., None] * (seg[:, 1:] - seg[:, :1])
    moved = np.stack([t_in > 0, t_out < 1], 1)  # ends cut at an edge: put them on it exactly, for the join
    edge = np.where(np.abs(out[..., 1] - low) < np.abs(out[..., 1] - high), low, high)
    out[..., 1] = np.where(moved, edge, out[..., 1])
    return out.astype(np.float32), t_out > t_in


def _join_at_cut(upper: np.ndarray, lower: np.ndarray, cut: int) -> np.ndarray:
    """Segments above and below a cut, each line's two pieces that meet on the cut joined into one."""
    on_up, on_low = upper[..., 1] == cut, lower[..., 1] == cut
    ui = np.nonzero(on_up[:, 0] != on_up[:, 1])[0]  # pieces with one end on the cut (not lying along it)
    li = np.nonzero(on_low[:, 0] != on_low[:, 1])[0]
    if len(ui) == 0 or len(li) == 0:
        return np.concatenate([upper, lower])
    # each piece as (point on the cut, far end)
    up = np.where(on_up[ui][:, 0, None, None], upper[ui], upper[ui, ::-1])
    low = np.where(on_low[li][:, 0, None, None], lower[li], lower[li, ::-1])
    du, dl = (_unit(p[:, 1] - p[:, 0]) for p in (up, low))
    normal = np.stack([-du[:, 1], du[:, 0]], -1)
    gap = np.abs(normal @ low[:, 0].T - (normal * up[:, 0]).sum(-1, keepdims=True))
    match = (np.abs(du @ dl.T) >= math.cos(math.radians(_JOIN_ANGLE))) & (gap <= _JOIN_GAP)
    # the closest pairs first (a stable sort: ties in row order), each piece in one pair at most
    ii, jj = np.nonzero(match)
    order = np.argsort(gap[ii, jj], kind="stable")
    pairs, used_low = {}, set()
    for i, j in zip(ii[order].tolist(), jj[order].tolist(), strict=True):
        if i not in pairs and j not in used_low:
            pairs[i] = j
            used_low.add(j)
    pick_up, pick_low = list(pairs), list(pairs.values())
    rest_up, rest_low = np.ones(len(upper), bool), np.ones(len(lower), bool)
    rest_up[ui[pick_up]], rest_low[li[pick_low]] = False, False
    joined = np.stack([up[pick_up, 1], low[pick_low, 1]], 1)  # (pairs, 2, 2), empty when none
    return np.concatenate([upper[rest_up], lower[rest_low], joined]).astype(np.float32)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True).clip(1e-9)


def longest_segments(segments: np.ndarray, min_length: float, max_segments: int) -> np.ndarray:
    """The segments the detection keeps of those found: at least ``min_length`` long, the ``max_segments`` longest,
    longest first (ties in their order). (N, 2, 2) -> (M, 2, 2); also for segments found elsewhere (a data set's).

    Example:
        >>> seg = np.array([[[0, 0], [5, 0]], [[0, 0], [30, 0]], [[0, 0], [0, 20]]], dtype=np.float32)
        >>> longest_segments(seg, 10.0, 512)[:, 1].tolist()
        [[30.0, 0.0], [0.0, 20.0]]
    """
    length = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=-1)
    order = np.argsort(-length, kind="stable")
    return segments[order[length[order] >= min_length][:max_segments]]


def pad_segments(segments: list[np.ndarray | Tensor], like: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Pad a list of (N_i, 2, 2) segment arrays to (B, N, 2, 2) with a (B, N) bool mask.

    Example:
        >>> seg, mask = pad_segments([np.zeros((2, 2, 2)), np.zeros((0, 2, 2))])
        >>> seg.shape, mask.tolist()
        (torch.Size([2, 2, 2, 2]), [[True, True], [False, False]])
    """
    kw = {"dtype": torch.float32} if like is None else {"device": like.device, "dtype": like.dtype}
    n = max([len(s) for s in segments] + [0])
    out = torch.zeros(len(segments), n, 2, 2, **kw)
    mask = torch.zeros(len(segments), n, dtype=torch.bool, device=out.device)
    for i, s in enumerate(segments):
        out[i, : len(s)] = torch.as_tensor(s).to(out)
        mask[i, : len(s)] = True
    return out, mask


def _to_gray_uint8(image: Tensor) -> np.ndarray:
    rgb = image.detach().float().clamp(0.0, 1.0).mul(255.0).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def detect_segments(
    image: str | Path | np.ndarray | Tensor,
    settings: SegmentSettings | None = None,
    meanwhile: Callable[[], object] | None = None,
) -> tuple[Tensor, Tensor]:
    """Detect line segments on an image or a batch: the one line-detection entry point of the package.

    Args:
        image: a float tensor (B, 3, H, W) or (3, H, W) of RGB in [0, 1] (values outside are clipped), on any
            device; or a file path or an image array as :func:`ngp_kornia.calibrate` accepts them (HxWx3 uint8 RGB;
            greyscale, RGBA, uint16 and float in [0, 1] are converted), which is one image. Arrays and files are
            detected on their 8-bit pixels, tensors on their pixels rounded to 8 bits: a tensor made of an 8-bit
            image (``uint8 / 255``) gives the same segments as the array.
        settings: the detection settings (see :func:`detect_segments_gray`); None for the defaults.
        meanwhile: a job this thread runs once, while it would wait for the last strip of line detection where
            strips run on other threads (:func:`detect_segments_gray`); its result is not kept.

    Returns:
        segments (B, N, 2, 2) in input pixels and mask (B, N), with B = 1 for an unbatched input; on a tensor's
        device and dtype, float32 on the CPU otherwise. An image with no lines has an all-False mask row.

    Raises:
        ShapeError: a tensor that is not (B, 3, H, W) or (3, H, W).
        TypeError: an integer tensor, or an input type that is not supported.
        ImageError: an unreadable file or an unsupported array.

    Example:
        >>> img = torch.zeros(1, 3, 64, 64); img[..., 20:44, 20:44] = 1.0
        >>> seg, mask = detect_segments(img)
        >>> int(mask.sum())
        4
    """
    gap = _once(meanwhile)
    if not isinstance(image, Tensor):
        gray = cv2.cvtColor(read_rgb(image), cv2.COLOR_RGB2GRAY)
        return pad_segments([detect_segments_gray(gray, settings, gap)])
    if not image.is_floating_point():
        raise TypeError(f"expected a float image tensor in [0, 1], got {image.dtype}; for uint8 use image.float()/255")
    images = image[None] if image.dim() == 3 else image
    KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
    found = [detect_segments_gray(_to_gray_uint8(im), settings, gap) for im in images]
    gap()  # an empty batch
    return pad_segments(found, like=images)


class LineDetector(torch.nn.Module):
    """Module form of :func:`detect_segments` (no parameters; LSD is not differentiable).

    Args:
        settings: the detection settings (see :func:`detect_segments`); None for the defaults.
    """

    def __init__(self, settings: SegmentSettings | None = None) -> None:
        super().__init__()
        self.settings = settings

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        return detect_segments(images, self.settings)
