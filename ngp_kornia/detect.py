"""Line-segment detection with OpenCV's LSD, returned as padded torch tensors.

LSD runs on a greyscale copy resized so its long side is at most ``working_size`` (aspect ratio kept); the
segments are mapped back to the input's pixels (pixel-centre convention), filtered by length and padded to
``(B, N, 2, 2)`` with a ``(B, N)`` mask. ``detector="fld"`` uses OpenCV's FastLineDetector (opencv-contrib's
ximgproc) instead: faster, and less accurate on the York Urban photos (see BENCHMARKS.md).
"""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np
import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from torch import Tensor

__all__ = ["DETECTORS", "LineDetector", "detect_segments", "detect_segments_gray", "pad_segments"]

#: line detectors :func:`detect_segments_gray` accepts
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


def detect_segments_gray(
    gray: np.ndarray,
    working_size: int = 640,
    min_length: float = 10.0,
    max_segments: int = 1024,
    detector: str = "lsd",
) -> np.ndarray:
    """Detect segments on one greyscale uint8 image.

    Args:
        gray: (H, W) uint8 image.
        working_size: LSD runs on a copy whose long side is at most this many pixels.
        min_length: segments shorter than this (in working-resolution pixels) are dropped.
        max_segments: keep at most this many, the longest first.
        detector: ``"lsd"`` (OpenCV's LSD) or ``"fld"`` (OpenCV's FastLineDetector).

    Returns:
        (N, 2, 2) float32 segments ``[[x0, y0], [x1, y1]]`` in the input's pixels, longest first.
    """
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


def _to_gray_uint8(image: Tensor) -> np.ndarray:
    rgb = image.detach().float().clamp(0.0, 1.0).mul(255.0).round().to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def detect_segments(
    images: Tensor,
    working_size: int = 640,
    min_length: float = 10.0,
    max_segments: int = 1024,
    detector: str = "lsd",
) -> tuple[Tensor, Tensor]:
    """Detect line segments on a batch of RGB images.

    Args:
        images: (B, 3, H, W) float RGB in [0, 1].
        working_size: LSD runs at this long side (smaller images are used as they are).
        min_length: minimum segment length in working-resolution pixels.
        max_segments: at most this many segments per image, the longest kept.
        detector: ``"lsd"`` or ``"fld"`` (see :func:`detect_segments_gray`).

    Returns:
        segments (B, N, 2, 2) in input pixels and mask (B, N), on the images' device and dtype. An image with no
        lines has an all-False mask row.

    Example:
        >>> img = torch.zeros(1, 3, 64, 64); img[..., 20:44, 20:44] = 1.0
        >>> seg, mask = detect_segments(img)
        >>> int(mask.sum())
        4
    """
    KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
    found = [
        detect_segments_gray(_to_gray_uint8(im), working_size, min_length, max_segments, detector) for im in images
    ]
    return pad_segments(found, like=images)


class LineDetector(torch.nn.Module):
    """Module form of :func:`detect_segments` (no parameters; LSD is not differentiable)."""

    def __init__(
        self, working_size: int = 640, min_length: float = 10.0, max_segments: int = 1024, detector: str = "lsd"
    ) -> None:
        super().__init__()
        self.working_size, self.min_length, self.max_segments = working_size, min_length, max_segments
        self.detector = detector

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        return detect_segments(images, self.working_size, self.min_length, self.max_segments, self.detector)
