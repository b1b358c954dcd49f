"""Projection, clipping and anti-aliased drawing of 3D polygons and segments with a pinhole camera.

Everything here is numpy (float64 geometry, uint8 images) because it runs inside the data renderer, one image at
a time, and must be fast. Conventions are those of :mod:`ngp_kornia.geometry.camera`: pixel-centre origin, OpenCV
camera frame, world y pointing down, ``x_cam = R @ (X_world - center)``.

Polygons are clipped in camera space, *before* projection, against the near plane and against a guard band
around the image (so nothing behind the camera is ever drawn and OpenCV never sees huge coordinates). They are
drawn with ``cv2.fillPoly`` / ``cv2.polylines`` with anti-aliasing and 1/16 px fixed-point coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["SHIFT", "Canvas", "PinholeView", "clip_polygon", "clip_segments"]

SHIFT = 4  # fractional bits of the fixed-point coordinates handed to OpenCV (1/16 pixel)
_SCALE = float(1 << SHIFT)


@dataclass
class PinholeView:
    """A calibrated camera looking at a world: intrinsics, world-to-camera rotation and position.

    Args:
        K: (3, 3) intrinsics.
        R: (3, 3) world-to-camera rotation.
        center: (3,) camera centre in world coordinates.
        width: image width in pixels.
        height: image height in pixels.
        near: near-plane distance; geometry closer than this along the optical axis is clipped away.
        guard: guard band, as a fraction of the image size added on every side, beyond which geometry is clipped.

    Example:
        >>> view = PinholeView(np.array([[100.0, 0, 31.5], [0, 100, 23.5], [0, 0, 1]]), np.eye(3), np.zeros(3),
        ...                    64, 48)
        >>> view.project(np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 10.0]]))
        array([[31.5, 23.5],
               [41.5, 23.5]])
    """

    K: np.ndarray
    R: np.ndarray
    center: np.ndarray
    width: int
    height: int
    near: float = 0.05
    guard: float = 0.5
    planes: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.near <= 0:
            raise ValueError(f"near must be positive, got {self.near}")
        self.K = np.asarray(self.K, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.planes = self._clip_planes()

    @property
    def focal(self) -> float:
        return float(self.K[0, 0])

    def _clip_planes(self) -> np.ndarray:
        """(5, 4) planes ``(n, d)`` in camera space, a point ``p`` is kept where ``n . p + d >= 0``."""
        f, cx, cy = self.K[0, 0], self.K[0, 2], self.K[1, 2]
        gx, gy = self.guard * self.width, self.guard * self.height
        x0, x1 = -0.5 - gx, self.width - 0.5 + gx
        y0, y1 = -0.5 - gy, self.height - 0.5 + gy
        # u = f x / z + cx >= x0  <=>  f x + (cx - x0) z >= 0 for z > 0, and likewise for the other sides
        planes = np.array(
            [
                [0.0, 0.0, 1.0, -self.near],
                [f, 0.0, cx - x0, 0.0],
                [-f, 0.0, x1 - cx, 0.0],
                [0.0, f, cy - y0, 0.0],
                [0.0, -f, y1 - cy, 0.0],
            ]
        )
        return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """World points (..., 3) to camera coordinates (..., 3)."""
        return (X - self.center) @ self.R.T

    def project_camera(self, Xc: np.ndarray) -> np.ndarray:
        """Camera-space points (..., 3) with ``z > 0`` to pixels (..., 2)."""
        f, cx, cy = self.K[0, 0], self.K[0, 2], self.K[1, 2]
        z = Xc[..., 2]
        return np.stack([f * Xc[..., 0] / z + cx, f * Xc[..., 1] / z + cy], -1)

    def project(self, X: np.ndarray) -> np.ndarray:
        """World points (..., 3) in front of the camera to pixels (..., 2)."""
        return self.project_camera(self.to_camera(X))


def clip_polygon(P: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clipping of one convex or concave planar polygon against half-spaces.

    Args:
        P: (k, 3) polygon vertices.
        planes: (n, 4) planes ``(a, b, c, d)``; the kept side is ``a x + b y + c z + d >= 0``.

    Returns:
        (k', 3) clipped polygon, possibly with fewer than 3 vertices when nothing is left.

    Example:
        >>> square = np.array([[-1.0, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]])
        >>> clip_polygon(square, np.array([[1.0, 0, 0, 0]]))[:, 0].tolist()  # keep x >= 0
        [0.0, 1.0, 1.0, 0.0]
    """
    for plane in planes:
        if len(P) == 0:
            break
        s = P @ plane[:3] + plane[3]
        inside = s >= 0
        if inside.all():
            continue
        if not inside.any():
            return P[:0]
        out = []
        k = len(P)
        for i in range(k):
            j = (i + 1) % k
            if inside[i]:
                out.append(P[i])
            if inside[i] != inside[j]:
                t = s[i] / (s[i] - s[j])
                out.append(P[i] + t * (P[j] - P[i]))
        P = np.array(out)
    return P


def clip_segments(A: np.ndarray, B: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Liang-Barsky clipping of many segments ``A[i] -> B[i]`` against half-spaces, vectorised.

    Args:
        A: (m, 3) segment starts.
        B: (m, 3) segment ends.
        planes: (n, 4) planes, the kept side is ``n . p + d >= 0``.

    Returns:
        The clipped starts (m', 3), ends (m', 3) and the indices (m',) of the segments that survive.

    Example:
        >>> a, b, keep = clip_segments(np.array([[-1.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[1.0, 0, 0, 0]]))
        >>> a.tolist(), b.tolist(), keep.tolist()
        ([[0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], [0])
    """
    t0 = np.zeros(len(A))
    t1 = np.ones(len(A))
    ok = np.ones(len(A), dtype=bool)
    D = B - A
    for plane in planes:
        sa = A @ plane[:3] + plane[3]
        ds = D @ plane[:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = -sa / ds
        t0 = np.where(ds > 0, np.maximum(t0, tc), t0)
        t1 = np.where(ds < 0, np.minimum(t1, tc), t1)
        ok &= ~((ds == 0) & (sa < 0))
    keep = np.flatnonzero(ok & (t0 <= t1))
    return A[keep] + t0[keep, None] * D[keep], A[keep] + t1[keep, None] * D[keep], keep


def _fixed(p: np.ndarray) -> np.ndarray:
    return np.round(p * _SCALE).astype(np.int32)


class Canvas:
    """An RGB uint8 image to draw world-space polygons and segments into, through a :class:`PinholeView`.

    Args:
        view: the camera.
        image: (H, W, 3) uint8 image, drawn into in place.
        antialias: anti-aliased edges (``cv2.LINE_AA``) or plain 8-connected ones.

    Example:
        >>> view = PinholeView(np.array([[50.0, 0, 15.5], [0, 50, 15.5], [0, 0, 1]]), np.eye(3), np.zeros(3), 32, 32)
        >>> canvas = Canvas(view, np.zeros((32, 32, 3), np.uint8))
        >>> quad = np.array([[[-1.0, -1, 5], [1, -1, 5], [1, 1, 5], [-1, 1, 5]]])
        >>> canvas.fill(quad, (255, 0, 0))
        >>> canvas.image[15, 15].tolist(), canvas.image[0, 0].tolist()
        ([255, 0, 0], [0, 0, 0])
    """

    def __init__(self, view: PinholeView, image: np.ndarray, antialias: bool = True) -> None:
        if image.ndim != 3 or image.shape[:2] != (view.height, view.width):
            raise ValueError(f"image must be ({view.height}, {view.width}, C), got {image.shape}")
        self.view = view
        self.image = image
        self.line_type = cv2.LINE_AA if antialias else cv2.LINE_8

    def project_polygons(self, polys: np.ndarray) -> list[np.ndarray] | np.ndarray:
        """Clip (m, k, 3) world polygons and project them to fixed-point pixel contours for OpenCV.

        Returns:
            An (m', k, 2) int32 array when no polygon needed clipping, else a list of (k_i, 2) int32 arrays.
        """
        view = self.view
        Xc = view.to_camera(polys)
        s = Xc @ view.planes[:, :3].T + view.planes[:, 3]  # (m, k, 5)
        inside = s >= 0
        all_in = inside.all(axis=(1, 2))
        # a polygon entirely on the wrong side of one plane is invisible
        dead = (~inside).all(axis=1).any(axis=1)
        cut = np.flatnonzero(~all_in & ~dead)
        whole = _fixed(view.project_camera(Xc[all_in]))
        if len(cut) == 0:
            return whole
        contours = list(whole)
        for i in cut:
            P = clip_polygon(Xc[i], view.planes)
            if len(P) >= 3:
                contours.append(_fixed(view.project_camera(P)))
        return contours

    def fill(self, polys: np.ndarray, color) -> None:
        """Fill (m, k, 3) world polygons with one colour. Overlapping polygons of one call cancel out (even-odd
        rule), so one call must hold non-overlapping polygons only."""
        contours = self.project_polygons(np.asarray(polys, dtype=np.float64))
        if len(contours):
            cv2.fillPoly(self.image, contours, _color(color), self.line_type, SHIFT)

    def lines(self, segs: np.ndarray, color, width: float, under=None) -> None:
        """Draw (m, 2, 3) world segments ``width`` world units wide (at their median depth).

        Args:
            segs: (m, 2, 3) segment end points.
            color: RGB colour.
            width: line width in world units; 0 draws 1 px lines.
            under: colour of the surface below; a line thinner than a pixel is then blended into it by its
                coverage, as a camera would, instead of being drawn as a full-strength 1 px line.
        """
        view = self.view
        segs = np.asarray(segs, dtype=np.float64)
        A, B, _ = clip_segments(view.to_camera(segs[:, 0]), view.to_camera(segs[:, 1]), view.planes)
        if len(A) == 0:
            return
        px = view.focal * width / float(np.median(0.5 * (A[:, 2] + B[:, 2]))) if width > 0 else 1.0
        color = np.asarray(color, dtype=np.float64)
        if px < 1.0 and under is not None:
            color = np.asarray(under, dtype=np.float64) + px * (color - np.asarray(under, dtype=np.float64))
        thickness = max(1, int(round(px)))
        pts = _fixed(np.stack([view.project_camera(A), view.project_camera(B)], 1))
        cv2.polylines(self.image, pts, False, _color(color), thickness, self.line_type, SHIFT)


def _color(color) -> tuple[float, float, float]:
    c = np.clip(np.asarray(color, dtype=np.float64), 0, 255)
    return float(c[0]), float(c[1]), float(c[2])
