"""Line-segment detection with OpenCV's LSD, returned as padded torch tensors.

:func:`detect_segments` is the one entry point: every caller (the parser, :func:`ngp_kornia.calibrate`, folder
prediction, the CLI overlay, the training cache, the benchmarks) gets its segments from it, with the settings of a
:class:`~ngp_kornia.models.ParserConfig` (``working_size``, ``min_length``, ``max_segments``), so all of them see
the same lines for the same image.

LSD runs on the 8-bit greyscale image resized so its long side is at most ``working_size`` (aspect ratio kept); the
segments are mapped back to the input's pixels (pixel-centre convention), filtered by length and padded to
``(B, N, 2, 2)`` with a ``(B, N)`` mask. ``ParserConfig(detector="fld")`` uses OpenCV's FastLineDetector
(opencv-contrib's ximgproc) instead: faster, and less accurate on real photos (see BENCHMARKS.md).
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

from ngp_kornia.io import read_rgb

if TYPE_CHECKING:  # the settings live beside the parser, which itself calls this module
    from ngp_kornia.models.parser import ParserConfig

__all__ = ["DETECTORS", "LineDetector", "detect_segments", "detect_segments_gray", "pad_segments"]

#: line detectors ``ParserConfig.detector`` accepts
DETECTORS = ("lsd", "fld")

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


def detect_segments_gray(gray: np.ndarray, config: ParserConfig | None = None) -> np.ndarray:
    """Detect segments on one greyscale uint8 image: the LSD step of :func:`detect_segments`.

    Args:
        gray: (H, W) uint8 image.
        config: the settings used: LSD runs on a copy whose long side is at most ``working_size`` pixels, segments
            shorter than ``min_length`` (working-resolution pixels) are dropped and at most ``max_segments`` kept,
            the longest first, found by ``detector`` (``"lsd"`` or ``"fld"``). None for the defaults of
            :class:`~ngp_kornia.models.ParserConfig`.

    Returns:
        (N, 2, 2) float32 segments ``[[x0, y0], [x1, y1]]`` in the input's pixels, longest first.
    """
    working_size, min_length, max_segments, detector = _settings(config)
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"expected an (H, W) uint8 greyscale image, got shape {gray.shape} dtype {gray.dtype}")
    if detector not in DETECTORS:
        raise ValueError(f"unknown line detector {detector!r}; choose one of {', '.join(DETECTORS)}")
    h, w = gray.shape
    scale = min(1.0, working_size / max(h, w))
    small = (
        gray if scale == 1.0 else cv2.resize(gray, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    )
    found = _lsd().detect(small)[0] if detector == "lsd" else _fld(min_length).detect(small)
    if found is None or found.size == 0:
        return np.zeros((0, 2, 2), np.float32)
    seg = found.reshape(-1, 2, 2).astype(np.float32)  # OpenCV 4 gives (N, 1, 4), OpenCV 5 (N, 4)
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=-1)
    order = np.argsort(-length, kind="stable")
    order = order[length[order] >= min_length][:max_segments]
    seg = seg[order]
    sx, sy = w / small.shape[1], h / small.shape[0]
    seg[..., 0] = (seg[..., 0] + 0.5) * sx - 0.5
    seg[..., 1] = (seg[..., 1] + 0.5) * sy - 0.5
    return seg


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


def _settings(config: ParserConfig | None) -> tuple[int, float, int, str]:
    if config is None:
        from ngp_kornia.models.parser import ParserConfig

        config = ParserConfig()
    return config.working_size, config.min_length, config.max_segments, config.detector


def _to_gray_uint8(image: Tensor) -> np.ndarray:
    rgb = image.detach().float().clamp(0.0, 1.0).mul(255.0).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def detect_segments(
    image: str | Path | np.ndarray | Tensor, config: ParserConfig | None = None
) -> tuple[Tensor, Tensor]:
    """Detect line segments on an image or a batch: the one line-detection entry point of the package.

    Args:
        image: a float tensor (B, 3, H, W) or (3, H, W) of RGB in [0, 1] (values outside are clipped), on any
            device; or a file path or an image array as :func:`ngp_kornia.calibrate` accepts them (HxWx3 uint8 RGB;
            greyscale, RGBA, uint16 and float in [0, 1] are converted), which is one image. Arrays and files are
            detected on their 8-bit pixels, tensors on their pixels rounded to 8 bits: a tensor made of an 8-bit
            image (``uint8 / 255``) gives the same segments as the array.
        config: a :class:`~ngp_kornia.models.ParserConfig` whose ``working_size``, ``min_length`` and
            ``max_segments`` are used (see :func:`detect_segments_gray`); None for the defaults.

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
    if not isinstance(image, Tensor):
        gray = cv2.cvtColor(read_rgb(image), cv2.COLOR_RGB2GRAY)
        return pad_segments([detect_segments_gray(gray, config)])
    if not image.is_floating_point():
        raise TypeError(f"expected a float image tensor in [0, 1], got {image.dtype}; for uint8 use image.float()/255")
    images = image[None] if image.dim() == 3 else image
    KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
    return pad_segments([detect_segments_gray(_to_gray_uint8(im), config) for im in images], like=images)


class LineDetector(torch.nn.Module):
    """Module form of :func:`detect_segments` (no parameters; LSD is not differentiable).

    Args:
        config: the detection settings (see :func:`detect_segments`); None for the defaults.
    """

    def __init__(self, config: ParserConfig | None = None) -> None:
        super().__init__()
        self.config = config

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        return detect_segments(images, self.config)
