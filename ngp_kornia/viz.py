"""Overlays: the horizon, the zenith direction, the vanishing points and the Manhattan frame drawn on the image (with
the true horizon beside the estimate when the ground truth is known) above a strip of the numbers and a key
(:mod:`ngp_kornia.viz_key`), and virtual objects (a box, the world axes) placed in the estimated Manhattan frame
(Fig. 1c-d of the paper)."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ngp_kornia.geometry import horizon_border_points, segment_vp_angle
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.viz_key import KeyEntry, key_strip

__all__ = [
    "BOX_EDGES",
    "LEGEND",
    "TRUTH_COLOUR",
    "draw_axes",
    "draw_calibration",
    "draw_frame_box",
    "draw_vanishing_points",
    "frame_box_points",
    "truth_horizon",
]

# RGB colours of the three Manhattan axes (x, vertical, z) and of the horizon
AXIS_COLOURS = ((230, 60, 60), (60, 200, 60), (70, 110, 255))
HORIZON_COLOUR = (255, 220, 0)
#: the true horizon's colour (a dashed line beside the estimate)
TRUTH_COLOUR = (255, 80, 255)

#: the twelve edges of a box as ``(corner, corner, world axis)``; bit ``a`` of a corner's index says on which side
#: of the box along world axis ``a`` it lies (for axis 1, bit set = the top face)
BOX_EDGES = tuple((i, i | 1 << axis, axis) for axis in range(3) for i in range(8) if not i >> axis & 1)
# without a given centre the box stands where the ray through this point (fractions of the width and height)
# meets the ground, one camera height below the camera, but never further than _MAX_DISTANCE camera heights
_BOX_ANCHOR = (0.5, 0.8)
_MAX_DISTANCE = 10.0
_BOX_HEIGHT = 0.2  # default size: the box looks about this fraction of the image height tall


def draw_calibration(
    image: np.ndarray,
    calibration: Calibration,
    segments: np.ndarray | None = None,
    tolerance_deg: float = 2.0,
    truth: object = None,
    vps: bool = True,
    key: bool = True,
) -> np.ndarray:
    """Draw a calibration over an HxWx3 uint8 RGB image (a copy, the photo as it is: not dimmed), with a strip
    below it that gives the answer's numbers and a key of everything drawn.

    Segments that point at one of the three VPs within ``tolerance_deg`` are drawn thin in that axis' colour (x
    red, vertical green, z blue), the others thin grey; the horizon is a yellow line, the up (zenith) direction a
    green arrow from the image centre, the VPs rings in their axis' colours where they lie in the image and arrows
    at its border towards those that do not (:func:`draw_vanishing_points`), the true horizon (given ``truth``) a
    dashed magenta line. The strip (:func:`~ngp_kornia.viz_key.key_strip`) sits below the photo, never over it.

    Args:
        image: (H, W, 3) uint8 RGB.
        calibration: an unbatched :class:`Calibration` for that image.
        segments: optional (N, 2, 2) segments in the image's pixels.
        tolerance_deg: angle for assigning segments to VPs.
        truth: the true horizon, a line ``(a, b, c)`` in the image's pixels, or a ground-truth record holding one
            under ``"horizon"`` (a manifest row, a render's record, a labelled image): see :func:`truth_horizon`.
        vps: draw the vanishing points.
        key: add the strip of numbers and key below the photo; False returns the drawing at the image's size.

    Returns:
        (H + strip, W, 3) uint8 RGB, the photo's rows first; (H, W, 3) without ``key``.
    """
    _check_unbatched(calibration, "draw_calibration")
    out = np.array(image, dtype=np.uint8, copy=True)
    h, w = out.shape[:2]
    thick = _thickness(out)
    entries = []
    if segments is not None and len(segments):
        _draw_segments(out, segments, calibration, tolerance_deg, max(1, round(max(h, w) / 800)))
        entries += [KeyEntry(name, colour, "line") for name, colour in LEGEND[:4]]
    (x0, y0), (x1, y1) = horizon_border_points(calibration.horizon[None].double(), w)[0].tolist()
    _outlined(cv2.line, out, (_pt(x0, y0), _pt(x1, y1)), HORIZON_COLOUR, 2 * thick)
    line = None if truth is None else truth_horizon(truth)
    if line is not None:  # over the estimate, thinner: where the two agree both still show
        _dashed_line(out, line, w, TRUTH_COLOUR, max(2, thick))
    entries += [KeyEntry(*LEGEND[4], "thick")] + ([KeyEntry("true horizon", TRUTH_COLOUR, "dashed")] if
                                                  line is not None else [])
    if _draw_zenith_arrow(out, calibration, thick):
        entries.append(KeyEntry("up, from the image centre", AXIS_COLOURS[1], "up"))
    shapes = _draw_vps(out, calibration, thick) if vps else set()
    entries += [KeyEntry(label, (255, 255, 255), shape) for shape, label in _VP_KEY if shape in shapes]
    return np.concatenate([out, key_strip(w, _numbers(calibration), entries)]) if key else out


#: the key's words for the two ways a vanishing point is drawn
_VP_KEY = (("ring", "vanishing point (axis colour)"), ("arrow", "towards a vanishing point off the image"))


def _numbers(cal: Calibration) -> list[str]:
    """The answer as the strip's first items: the camera, then its confidence and standard deviations."""
    if not bool(cal.valid):
        return ["no camera found (valid false): a level guess"]
    items = [f"focal {float(cal.focal):.0f} px", f"FoV v {float(cal.fov_v):.1f} deg",
             f"pitch {float(cal.pitch):.1f} deg", f"roll {float(cal.roll):.1f} deg"]
    if cal.confidence is not None:
        items.append(f"confidence {float(cal.confidence):.2f}")
    if cal.pitch_std is not None:
        stds = (float(cal.pitch_std), float(cal.roll_std), float(cal.fov_v_std))
        items.append("std: pitch {:.1f}, roll {:.1f}, FoV {:.1f} deg".format(*stds))
    return items


def _outlined(draw, out: np.ndarray, points: tuple, colour, thick: int, **kwargs) -> None:
    """``draw(out, *points, colour, thick)`` over a dark outline one pixel wider each side, so that it reads on
    any photo."""
    draw(out, *points, (20, 20, 20), thick + 2, cv2.LINE_AA, **kwargs)
    draw(out, *points, colour, thick, cv2.LINE_AA, **kwargs)


def truth_horizon(truth: object) -> np.ndarray:
    """The true horizon ``(a, b, c)`` (3,) float64 of a line or of a ground-truth record: a sequence, array or
    tensor of three numbers, or an object or mapping with a ``horizon`` of them (a render's ``ground_truth.json``
    record, a manifest's sample, an evaluation :class:`~ngp_kornia.evaluation.datasets.LabelledImage`).

    Raises:
        ValueError: no horizon of three finite numbers in it.
    """
    value = truth.get("horizon") if isinstance(truth, dict) else getattr(truth, "horizon", truth)
    try:
        line = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value, dtype=np.float64)
    except (TypeError, ValueError):
        line = np.zeros(0)
    if line.shape != (3,) or not np.isfinite(line).all() or not np.any(line[:2]):
        raise ValueError(f"the true horizon must be a line (a, b, c) of three finite numbers, got {value!r}")
    return line


def _dashed_line(out: np.ndarray, line: np.ndarray, width: int, colour, thick: int) -> None:
    """A dashed line across the image (dashes about 2% of the width)."""
    (x0, y0), (x1, y1) = horizon_border_points(torch.from_numpy(line)[None], width)[0].tolist()
    length = float(np.hypot(x1 - x0, y1 - y0))
    count = max(2, int(length / max(8.0, 0.02 * width)))
    for i in range(0, count, 2):
        a, b = i / count, min(1.0, (i + 1) / count)
        cv2.line(out, _pt(x0 + a * (x1 - x0), y0 + a * (y1 - y0)), _pt(x0 + b * (x1 - x0), y0 + b * (y1 - y0)),
                 colour, thick, cv2.LINE_AA)


def draw_vanishing_points(out: np.ndarray, calibration: Calibration, thick: int = 1) -> np.ndarray:
    """Draw the three VPs on ``out`` (H, W, 3) uint8 RGB, in place: a ring in the axis' colour where a VP lies in
    the image, else an arrow at the border pointing towards it (both ways for one at infinity, whose direction has
    no sign). Returns ``out``."""
    _draw_vps(out, calibration, thick)
    return out


def _draw_vps(out: np.ndarray, calibration: Calibration, thick: int) -> set[str]:
    """:func:`draw_vanishing_points`; the shapes drawn (``"ring"``, ``"arrow"``), for the key."""
    h, w = out.shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    radius, margin, shapes = max(4, 5 * thick), 4 * thick + 8, set()
    for axis, vp in enumerate(calibration.vps.detach().cpu().double().numpy()):
        colour = AXIS_COLOURS[axis]
        if abs(vp[2]) > 1e-9 * np.abs(vp).max():
            point = vp[:2] / vp[2]
            if (point >= margin).all() and point[0] <= w - 1 - margin and point[1] <= h - 1 - margin:
                _outlined(cv2.circle, out, (_pt(*point), radius), colour, 2 * thick)
                cv2.drawMarker(out, _pt(*point), colour, cv2.MARKER_CROSS, radius, thick, cv2.LINE_AA)
                shapes.add("ring")
                continue
            directions = [point - centre]
        else:
            directions = [vp[:2], -vp[:2]]
        for d in directions:
            _border_arrow(out, centre, d, colour, thick, margin)
            shapes.add("arrow")
    return shapes


def _border_arrow(out: np.ndarray, centre: np.ndarray, direction: np.ndarray, colour, thick: int, margin: int) -> None:
    """A pointer (a filled triangle, outlined dark) just inside the image's border, pointing from the centre along
    ``direction``: shaped apart from the up arrow, which is a line."""
    h, w = out.shape[:2]
    norm = float(np.linalg.norm(direction))
    if norm == 0:
        return
    d = direction / norm
    half = np.array([(w - 1) / 2.0 - margin, (h - 1) / 2.0 - margin])
    reach = float(np.min(np.where(np.abs(d) > 1e-12, half / np.maximum(np.abs(d), 1e-12), np.inf)))
    tip, side, size = centre + d * reach, np.array([-d[1], d[0]]), max(6.0, 0.025 * max(h, w))
    back = tip - d * 1.7 * size
    triangle = np.array([_pt(*tip), _pt(*(back + side * size)), _pt(*(back - side * size))])
    cv2.fillPoly(out, [triangle], colour, cv2.LINE_AA)
    cv2.polylines(out, [triangle], True, (20, 20, 20), max(1, thick), cv2.LINE_AA)


#: the colours of :func:`draw_calibration`'s lines, as its key names them: (name, RGB colour)
LEGEND = (
    ("x-axis lines", AXIS_COLOURS[0]),
    ("vertical lines", AXIS_COLOURS[1]),
    ("z-axis lines", AXIS_COLOURS[2]),
    ("other lines", (150, 150, 150)),
    ("horizon", HORIZON_COLOUR),
)


def _pt(x: float, y: float) -> tuple[int, int]:
    big = 1 << 20  # keep far-away points inside what OpenCV can draw
    return int(np.clip(round(x), -big, big)), int(np.clip(round(y), -big, big))


def _draw_segments(out: np.ndarray, segments: np.ndarray, cal: Calibration, tol: float, thick: int) -> None:
    """Thin segments in the colour of the VP they point at (grey for the others, drawn first, underneath)."""
    seg = torch.as_tensor(segments, dtype=torch.float64)[None]
    angle = segment_vp_angle(seg, cal.vps.double()[None])[0]  # (3, N)
    best, axis = angle.min(0)
    lines = list(zip(segments.tolist(), best.tolist(), axis.tolist(), strict=True))
    for (p, q), a, i in sorted(lines, key=lambda line: line[1] < tol):
        cv2.line(out, _pt(*p), _pt(*q), AXIS_COLOURS[i] if a < tol else LEGEND[3][1], thick, cv2.LINE_AA)


def _draw_zenith_arrow(out: np.ndarray, cal: Calibration, thick: int) -> bool:
    """The up direction as an arrow from the image centre; whether one was drawn (none for a camera looking
    straight up or down)."""
    # at the image centre the world's up direction projects along (up_x, up_y): the way vertical lines rise there
    h, w = out.shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    direction = cal.up[:2].double().numpy()
    norm = np.linalg.norm(direction)
    if norm == 0:
        return False
    tip = centre + direction / norm * 0.2 * h
    _outlined(cv2.arrowedLine, out, (_pt(*centre), _pt(*tip)), AXIS_COLOURS[1], 2 * thick, tipLength=0.2)
    _outlined(cv2.circle, out, (_pt(*centre), 2 * thick + 1), AXIS_COLOURS[1], -1)  # its foot: the image centre
    return True


def frame_box_points(
    calibration: Calibration, center: np.ndarray | None = None, size: float | None = None
) -> np.ndarray:
    """Pixels of the corners of a cube aligned with the calibration's Manhattan frame.

    The camera sits at the world origin and the world's y axis points down (README "Conventions"); lengths are in
    camera heights, so the ground is the plane ``y = 1``. The cube stands on its bottom face, centred at ``center``,
    with edges along the world axes: vertical edges vanish at the zenith, the others at the two horizontal VPs.

    Args:
        calibration: an unbatched :class:`Calibration` (``K`` and ``R`` are used).
        center: (3,) world position of the centre of the bottom face. Default: the ground point seen at the
            lower middle of the image (on the ray through it, at most 10 camera heights away when the ground is
            not visible there).
        size: edge length in camera heights. Default: the cube looks about a fifth of the image height tall.

    Returns:
        (8, 2) float64 pixels; corner ``i`` has bit 0 of ``i`` set on the +x side, bit 1 on the top and bit 2 on
        the +z side (:data:`BOX_EDGES` lists the edges). Corners at or behind the camera are NaN.

    Example:
        >>> from ngp_kornia import calibrate
        >>> cal = calibrate(torch.rand(3, 48, 64))
        >>> frame_box_points(cal).shape
        (8, 2)
    """
    _check_unbatched(calibration, "frame_box_points")
    points = _box_homogeneous(calibration, center, size)
    pixels = np.full((8, 2), np.nan)
    front = points[:, 2] > 0
    pixels[front] = points[front, :2] / points[front, 2:]
    return pixels


def draw_frame_box(
    image: np.ndarray, calibration: Calibration, center: np.ndarray | None = None, size: float | None = None
) -> np.ndarray:
    """Draw a wireframe cube standing upright in the estimated Manhattan frame (virtual object insertion).

    Edges along world x are red, vertical edges green and edges along world z blue (the colours of
    :func:`draw_calibration`). Parts of the cube behind the camera or outside the image are clipped away.

    Args:
        image: (H, W, 3) uint8 RGB.
        calibration: an unbatched :class:`Calibration` for that image.
        center: (3,) world position of the centre of the cube's bottom face, in camera heights; see
            :func:`frame_box_points` for the default.
        size: edge length in camera heights; see :func:`frame_box_points` for the default.

    Returns:
        (H, W, 3) uint8 RGB, a copy.

    Example:
        >>> from ngp_kornia import calibrate
        >>> cal = calibrate(torch.rand(3, 48, 64))
        >>> draw_frame_box(np.zeros((48, 64, 3), np.uint8), cal).shape
        (48, 64, 3)
    """
    _check_unbatched(calibration, "draw_frame_box")
    out = image.copy()
    points = _box_homogeneous(calibration, center, size)
    thick = 2 * _thickness(out)
    for i, j, axis in BOX_EDGES:
        clipped = _clip_edge(points[i], points[j], out.shape[:2])
        if clipped is not None:
            p, q, _ = clipped
            cv2.line(out, _pt(*p), _pt(*q), AXIS_COLOURS[axis], thick, cv2.LINE_AA)
    return out


def draw_axes(
    image: np.ndarray, calibration: Calibration, origin: np.ndarray | None = None, length: float | None = None
) -> np.ndarray:
    """Draw the estimated Manhattan frame as three arrows from a world point: world x (red), up (green, world
    -y) and world z (blue).

    Args:
        image: (H, W, 3) uint8 RGB.
        calibration: an unbatched :class:`Calibration` for that image.
        origin: (3,) world point the arrows start from, in camera heights; default: where
            :func:`draw_frame_box` puts its cube.
        length: arrow length in camera heights; default: the default cube's edge length.

    Returns:
        (H, W, 3) uint8 RGB, a copy.

    Example:
        >>> from ngp_kornia import calibrate
        >>> cal = calibrate(torch.rand(3, 48, 64))
        >>> draw_axes(np.zeros((48, 64, 3), np.uint8), cal).shape
        (48, 64, 3)
    """
    _check_unbatched(calibration, "draw_axes")
    out = image.copy()
    K, R, shape = _camera(calibration)
    origin, length = _placement(K, R, shape, origin, length)
    tips = origin + length * np.diag([1.0, -1.0, 1.0])  # x, up (world y points down), z
    thick = 2 * _thickness(out)
    for axis, tip in enumerate(tips):
        clipped = _clip_edge(K @ R @ origin, K @ R @ tip, out.shape[:2])
        if clipped is None:
            continue
        p, q, tip_visible = clipped
        if tip_visible:  # an arrow head only where the tip itself is in view
            cv2.arrowedLine(out, _pt(*p), _pt(*q), AXIS_COLOURS[axis], thick, cv2.LINE_AA, tipLength=0.15)
        else:
            cv2.line(out, _pt(*p), _pt(*q), AXIS_COLOURS[axis], thick, cv2.LINE_AA)
    return out


def _check_unbatched(calibration: Calibration, name: str) -> None:
    if calibration.batched:
        raise ValueError(f"{name} takes one image's Calibration; index the batch first (result[i])")


def _thickness(image: np.ndarray) -> int:
    return max(1, round(max(image.shape[:2]) / 400))


def _camera(calibration: Calibration) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    K = calibration.K.detach().cpu().double().numpy()
    R = calibration.R.detach().cpu().double().numpy()
    height, width = (int(v) for v in calibration.image_size)
    return K, R, (height, width)


def _placement(
    K: np.ndarray, R: np.ndarray, shape: tuple[int, int], center: np.ndarray | None, size: float | None
) -> tuple[np.ndarray, float]:
    """The box's bottom-centre and edge length, filling in the defaults."""
    height, width = shape
    if center is None:
        anchor = np.array([_BOX_ANCHOR[0] * (width - 1), _BOX_ANCHOR[1] * (height - 1), 1.0])
        ray = R.T @ np.linalg.solve(K, anchor)  # world direction of the anchor pixel's ray
        ray /= np.linalg.norm(ray)
        # world y points down and the ground is y = 1: a ray going down by ray_y per unit meets it at 1 / ray_y
        center = ray * (1.0 / ray[1] if ray[1] > 1.0 / _MAX_DISTANCE else _MAX_DISTANCE)
    center = np.asarray(center, dtype=np.float64).reshape(3)
    if size is None:  # an object of size s at distance d looks about f s / d pixels tall
        size = _BOX_HEIGHT * height / K[1, 1] * float(np.linalg.norm(center))
    return center, float(size)


def _box_homogeneous(calibration: Calibration, center: np.ndarray | None, size: float | None) -> np.ndarray:
    """(8, 3) corners of the box as homogeneous pixels ``K R X``, whose last coordinate is the depth."""
    K, R, shape = _camera(calibration)
    center, size = _placement(K, R, shape, center, size)
    bits = (np.arange(8)[:, None] >> np.arange(3)) & 1
    offsets = np.stack([bits[:, 0] - 0.5, -bits[:, 1], bits[:, 2] - 0.5], -1)  # the top is at -y (up)
    return (center + size * offsets) @ (K @ R).T


def _clip_edge(
    a: np.ndarray, b: np.ndarray, shape: tuple[int, int]
) -> tuple[tuple[float, float], tuple[float, float], bool] | None:
    """The part of a 3D edge that is in front of the camera and projects into the image (plus a small margin).

    Clipping happens on homogeneous pixels ``h = K R X`` before dividing by the depth ``h_w``: each bound is a
    linear constraint on ``h`` (``h_w > 0``, ``x_min h_w <= h_x <= x_max h_w``, the same for y), so it is linear
    along the edge too, and a corner behind the camera never gets a pixel of its own.

    Returns:
        the two end pixels and whether ``b`` itself was kept, or None when nothing of the edge is visible.
    """
    h, w = shape
    margin = 2.0
    x0, y0, x1, y1 = -margin, -margin, w - 1 + margin, h - 1 + margin
    near = 1e-9 * max(np.abs(a).max(), np.abs(b).max(), 1e-300)
    # each row (c, d) is the constraint c . h + d >= 0
    bounds = [((0, 0, 1), -near), ((1, 0, -x0), 0), ((-1, 0, x1), 0), ((0, 1, -y0), 0), ((0, -1, y1), 0)]
    lo, hi = 0.0, 1.0
    for c, d in bounds:
        ga, gb = float(np.dot(c, a)) + d, float(np.dot(c, b)) + d
        if ga < 0 and gb < 0:
            return None
        if ga < 0:
            lo = max(lo, ga / (ga - gb))
        elif gb < 0:
            hi = min(hi, ga / (ga - gb))
    if lo > hi:
        return None
    p, q = a + lo * (b - a), a + hi * (b - a)
    return (p[0] / p[2], p[1] / p[2]), (q[0] / q[2], q[1] / q[2]), hi == 1.0
