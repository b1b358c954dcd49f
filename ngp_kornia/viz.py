"""Overlays: the horizon, the zenith direction and the Manhattan frame drawn on the image."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ngp_kornia.geometry import horizon_border_points, segment_vp_angle
from ngp_kornia.models.result import Calibration

__all__ = ["draw_calibration"]

# RGB colours of the three Manhattan axes (x, vertical, z) and of the horizon
AXIS_COLOURS = ((230, 60, 60), (60, 200, 60), (70, 110, 255))
HORIZON_COLOUR = (255, 220, 0)


def draw_calibration(
    image: np.ndarray, calibration: Calibration, segments: np.ndarray | None = None, tolerance_deg: float = 2.0
) -> np.ndarray:
    """Draw a calibration on an HxWx3 uint8 RGB image (returns a copy).

    Segments that point at one of the three VPs within ``tolerance_deg`` are drawn in that axis' colour (x red,
    vertical green, z blue); the horizon is a yellow line, the up (zenith) direction an arrow at the image centre, and
    the estimate is written in the top-left corner.

    Args:
        image: (H, W, 3) uint8 RGB.
        calibration: an unbatched :class:`Calibration` for that image.
        segments: optional (N, 2, 2) segments in the image's pixels.
        tolerance_deg: angle for assigning segments to VPs.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    if calibration.batched:
        raise ValueError("draw_calibration takes one image's Calibration; index the batch first (result[i])")
    out = (image.astype(np.float32) * 0.6).astype(np.uint8)  # dim the photo so the drawing stands out
    h, w = out.shape[:2]
    thick = max(1, round(max(h, w) / 400))
    if segments is not None and len(segments):
        _draw_segments(out, segments, calibration, tolerance_deg, thick)
    (x0, y0), (x1, y1) = horizon_border_points(calibration.horizon[None].double(), w)[0].tolist()
    cv2.line(out, _pt(x0, y0), _pt(x1, y1), HORIZON_COLOUR, 2 * thick, cv2.LINE_AA)
    _draw_zenith_arrow(out, calibration, thick)
    text = (
        f"f={float(calibration.focal):.0f}px  vFoV={float(calibration.fov_v):.1f}  "
        f"pitch={float(calibration.pitch):.1f}  roll={float(calibration.roll):.1f}"
    )
    scale = max(0.4, max(h, w) / 1400)
    cv2.putText(
        out, text, (8, int(24 * scale / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA
    )
    return out


def _pt(x: float, y: float) -> tuple[int, int]:
    big = 1 << 20  # keep far-away points inside what OpenCV can draw
    return int(np.clip(round(x), -big, big)), int(np.clip(round(y), -big, big))


def _draw_segments(out: np.ndarray, segments: np.ndarray, cal: Calibration, tol: float, thick: int) -> None:
    seg = torch.as_tensor(segments, dtype=torch.float64)[None]
    angle = segment_vp_angle(seg, cal.vps.double()[None])[0]  # (3, N)
    best, axis = angle.min(0)
    for (p, q), a, i in zip(segments.tolist(), best.tolist(), axis.tolist(), strict=True):
        colour = AXIS_COLOURS[i] if a < tol else (150, 150, 150)
        cv2.line(out, _pt(*p), _pt(*q), colour, thick if a < tol else 1, cv2.LINE_AA)


def _draw_zenith_arrow(out: np.ndarray, cal: Calibration, thick: int) -> None:
    # at the image centre the world's up direction projects along (up_x, up_y): the way vertical lines rise there
    h, w = out.shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    direction = cal.up[:2].double().numpy()
    norm = np.linalg.norm(direction)
    if norm == 0:
        return
    tip = centre + direction / norm * 0.2 * h
    cv2.arrowedLine(out, _pt(*centre), _pt(*tip), AXIS_COLOURS[1], 2 * thick, cv2.LINE_AA, tipLength=0.2)
