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

__all__ = ["SHIFT", "Canvas", "DrawList", "PinholeView", "clip_polygon", "clip_segments"]

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
        guard: guard band, as a fraction of the image size added on every side, beyond which geometry is clipped
            (clipping at the image border itself would add artificial edges under the anti-aliasing).

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
    guard: float = 2.0
    planes: np.ndarray = field(init=False, repr=False)
    frustum: np.ndarray = field(init=False, repr=False)
    world_frustum: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.near <= 0:
            raise ValueError(f"near must be positive, got {self.near}")
        self.K = np.asarray(self.K, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.planes = self._clip_planes(self.guard)
        self.frustum = self._clip_planes(2.0 / max(self.width, self.height))
        # world-space version of the frustum planes, to test world points without transforming them
        self.world_frustum = np.concatenate(
            [self.frustum[:, :3] @ self.R, (self.frustum[:, 3] - self.frustum[:, :3] @ self.R @ self.center)[:, None]],
            1,
        )

    @property
    def focal(self) -> float:
        return float(self.K[0, 0])

    def _clip_planes(self, guard: float) -> np.ndarray:
        """(5, 4) planes ``(n, d)`` in camera space, a point ``p`` is kept where ``n . p + d >= 0``: the near plane
        and the image borders pushed out by ``guard`` times the image size."""
        f, cx, cy = self.K[0, 0], self.K[0, 2], self.K[1, 2]
        gx, gy = guard * self.width, guard * self.height
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

    def sees(self, X: np.ndarray) -> bool:
        """Whether the convex hull of world points (n, 3) may be in view: False when all of them lie outside one
        side of the view frustum."""
        s = X @ self.world_frustum[:, :3].T + self.world_frustum[:, 3]
        return not bool((s < 0).all(0).any())

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """World points (..., 3) to camera coordinates (..., 3)."""
        return (X - self.center) @ self.R.T

    def project_camera(self, Xc: np.ndarray) -> np.ndarray:
        """Camera-space points (..., 3) with ``z > 0`` to pixels (..., 2).

        Not kornia's ``project_points`` (the same pixels): the renderer's geometry is numpy, and the torch round
        trip costs about 8x the projection on a polygon's corners.
        """
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


class DrawList:
    """Polygons and segments queued in drawing order, then projected and clipped all at once and drawn.

    Queuing is cheap; :meth:`draw` does the geometry for every queued primitive in a few vectorised numpy calls,
    so a scene of thousands of small polygons costs little more than the OpenCV calls themselves.

    Example:
        >>> view = PinholeView(np.array([[50.0, 0, 15.5], [0, 50, 15.5], [0, 0, 1]]), np.eye(3), np.zeros(3), 32, 32)
        >>> todo = DrawList()
        >>> todo.fill(np.array([[[-1.0, -1, 5], [1, -1, 5], [1, 1, 5], [-1, 1, 5]]]), (0, 255, 0))
        >>> todo.lines(np.array([[[-1.0, -0.05, 5], [1, -0.05, 5]]]), (255, 0, 0), 0.0)
        >>> image = np.zeros((32, 32, 3), np.uint8)
        >>> todo.draw(view, image)
        >>> bool(image[15, 15, 0] > 200), image[10, 15].tolist(), image[0, 0].tolist()  # line, quad, nothing
        (True, [0, 255, 0], [0, 0, 0])
    """

    def __init__(self) -> None:
        self._cmds: list[tuple] = []
        self._polys: dict[int, list[np.ndarray]] = {}
        self._npoly: dict[int, int] = {}
        self._segs: list[np.ndarray] = []
        self._nseg = 0

    def fill(self, polys: np.ndarray, color) -> None:
        """Queue (m, k, 3) world polygons filled with one colour. One call must hold non-overlapping polygons
        (OpenCV fills several contours with the even-odd rule)."""
        polys = np.asarray(polys, dtype=np.float64)
        m, k = polys.shape[:2]
        if m == 0:
            return
        start = self._npoly.get(k, 0)
        self._polys.setdefault(k, []).append(polys)
        self._npoly[k] = start + m
        self._cmds.append((0, k, start, start + m, _color(color)))

    def lines(self, segs: np.ndarray, color, width: float, under=None) -> None:
        """Queue (m, 2, 3) world segments ``width`` world units wide (0: one pixel). With ``under``, the colour of
        the surface below, a line thinner than a pixel is blended into it by its coverage, as a camera would."""
        segs = np.asarray(segs, dtype=np.float64)
        if len(segs) == 0:
            return
        start = self._nseg
        self._segs.append(segs)
        self._nseg += len(segs)
        self._cmds.append((1, 0, start, self._nseg, (color, float(width), under)))

    def draw(self, view: PinholeView, image: np.ndarray, antialias: bool = True, min_width: float = 0.0) -> None:
        """Clip, project and draw everything queued, in order, into ``image`` (H, W, 3) uint8; lines narrower than
        ``min_width`` pixels are left out."""
        line_type = cv2.LINE_AA if antialias else cv2.LINE_8
        polys = {k: _project_batch(view, np.concatenate(v)) for k, v in self._polys.items()}
        segs = _project_segments(view, np.concatenate(self._segs)) if self._segs else None
        for kind, k, a, b, arg in self._cmds:
            if kind == 0:
                contours = _contours(view, polys[k], a, b)
                if len(contours):
                    cv2.fillPoly(image, contours, arg, line_type, SHIFT)
                continue
            pts, keep, depth = segs
            sel = keep[a:b]
            if not sel.any():
                continue
            color, width, under = arg
            px = view.focal * width / float(depth[a:b][sel].mean()) if width > 0 else 1.0
            if px < min_width:
                continue
            if px < 1.0 and under is not None:
                c, u = np.asarray(color, dtype=np.float64), np.asarray(under, dtype=np.float64)
                color = u + px * (c - u)
            cv2.polylines(image, pts[a:b][sel], False, _color(color), max(1, int(round(px))), line_type, SHIFT)


def _project_batch(view: PinholeView, P: np.ndarray):
    """Project (M, k, 3) world polygons: fixed-point pixels (M, k, 2), camera coordinates, and which polygons are
    entirely inside the clip volume or entirely outside one of its planes."""
    Xc = view.to_camera(P)
    s = Xc @ view.planes[:, :3].T + view.planes[:, 3]  # (M, k, 5)
    inside = s >= 0
    all_in = inside.reshape(len(P), -1).all(1)
    dead = ~inside.any(1).all(1)
    z = np.where(all_in[:, None], Xc[..., 2], 1.0)
    f, cx, cy = view.focal, view.K[0, 2], view.K[1, 2]
    pix = np.stack([f * Xc[..., 0] / z + cx, f * Xc[..., 1] / z + cy], -1)
    pix = np.where(all_in[:, None, None], pix, 0.0)
    return _fixed(pix), Xc, all_in, dead


def _contours(view: PinholeView, batch, a: int, b: int):
    pix, Xc, all_in, dead = batch
    if b - a == 1 and (all_in[a] or dead[a]):  # the common case of a single face, without numpy indexing
        return pix[a:b] if all_in[a] else ()
    ok = all_in[a:b]
    cut = np.flatnonzero(~ok & ~dead[a:b])
    whole = pix[a:b][ok]
    if len(cut) == 0:
        return whole
    contours = list(whole)
    for i in cut:
        P = clip_polygon(Xc[a + i], view.planes)
        if len(P) >= 3:
            contours.append(_fixed(view.project_camera(P)))
    return contours


def _project_segments(view: PinholeView, S: np.ndarray):
    """Clip and project (M, 2, 3) world segments: fixed-point pixels (M, 2, 2), kept mask (M,), mean depth (M,)."""
    A, B = view.to_camera(S[:, 0]), view.to_camera(S[:, 1])
    A2, B2, keep = clip_segments(A, B, view.planes)
    mask = np.zeros(len(S), dtype=bool)
    mask[keep] = True
    pts = np.zeros((len(S), 2, 2), dtype=np.int32)
    pts[keep] = _fixed(np.stack([view.project_camera(A2), view.project_camera(B2)], 1))
    depth = np.ones(len(S))
    depth[keep] = 0.5 * (A2[:, 2] + B2[:, 2])
    return pts, mask, depth


class Canvas:
    """An RGB uint8 image to draw world-space polygons and segments into right away, through a
    :class:`PinholeView` (use :class:`DrawList` to draw many primitives fast).

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
        self.antialias = antialias

    def fill(self, polys: np.ndarray, color) -> None:
        """Fill (m, k, 3) non-overlapping world polygons with one colour."""
        todo = DrawList()
        todo.fill(polys, color)
        todo.draw(self.view, self.image, self.antialias)

    def lines(self, segs: np.ndarray, color, width: float, under=None) -> None:
        """Draw (m, 2, 3) world segments, see :meth:`DrawList.lines`."""
        todo = DrawList()
        todo.lines(segs, color, width, under)
        todo.draw(self.view, self.image, self.antialias)


def _color(color) -> tuple[float, float, float]:
    r, g, b = (min(max(float(c), 0.0), 255.0) for c in color)
    return r, g, b
