"""Per-pixel stages of the renderer: sky and ground, haze on the ground, and camera-like degradations.

They work in place, channel by channel, in float32 scratch buffers kept per thread and image size: fresh
image-sized temporaries cost more than the arithmetic itself (each is a new memory mapping, page-faulted in),
and numpy is slow at broadcasting a 3-vector over an (H, W, 3) image.
"""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np

from ngp_kornia.training.synth.painter import PinholeView

__all__ = ["foliage_texture", "ground_haze", "photometric", "sky_and_ground", "view_rays"]

_local = threading.local()


def _buffer(name: str, shape: tuple[int, int]) -> np.ndarray:
    """A float32 scratch array of this thread, reused across renders of the same size (contents undefined)."""
    cache = getattr(_local, "buffers", None)
    if cache is None or cache.get("shape") != shape:
        cache = _local.buffers = {"shape": shape}  # a new size: drop the old buffers
    buf = cache.get(name)
    if buf is None:
        buf = cache[name] = np.empty(shape, np.float32)
    return buf


def _vignette(shape: tuple[int, int]) -> np.ndarray:
    """Squared distance to the image centre, 1 at the middle of the borders, cached per thread and size."""
    cache = getattr(_local, "buffers", None)
    if cache is None or "r2" not in cache or cache.get("shape") != shape:
        H, W = shape
        x = np.linspace(-1.0, 1.0, W, dtype=np.float32)[None, :]
        y = np.linspace(-1.0, 1.0, H, dtype=np.float32)[:, None]
        np.add(x * x, y * y, out=_buffer("r2", shape))
    return _local.buffers["r2"]


def view_rays(view: PinholeView) -> np.ndarray:
    """Per pixel, the world-down component of the unit viewing ray (> 0 below the horizon).

    Returns:
        (H, W) float32, a scratch buffer: valid until the next call in this thread.

    Example:
        >>> view = PinholeView(np.array([[10.0, 0, 1.5], [0, 10, 1.5], [0, 0, 1]]), np.eye(3), np.zeros(3), 4, 4)
        >>> bool(view_rays(view)[0, 0] < 0 < view_rays(view)[3, 0])  # level camera: above / below the middle row
        True
    """
    H, W = view.height, view.width
    f, cx, cy = view.focal, view.K[0, 2], view.K[1, 2]
    x = ((np.arange(W, dtype=np.float32) - np.float32(cx)) / np.float32(f))[None, :]
    y = ((np.arange(H, dtype=np.float32) - np.float32(cy)) / np.float32(f))[:, None]
    d = view.R[:, 1].astype(np.float32)  # the world y (down) axis in camera coordinates
    out, norm = _buffer("sin_down", (H, W)), _buffer("norm", (H, W))
    np.add(d[0] * x, d[1] * y + d[2], out=out)
    np.add(x * x, y * y + np.float32(1.0), out=norm)
    np.sqrt(norm, out=norm)
    out /= norm
    return out


def sky_and_ground(view: PinholeView, ground, sky, sin_down: np.ndarray) -> np.ndarray:
    """Sky above the horizon and bare ground below, with an exactly placed, anti-aliased boundary.

    Args:
        view: the camera.
        ground: RGB colour of the ground (lit).
        sky: RGB colours ``(zenith, horizon)``.
        sin_down: :func:`view_rays` of the view.

    Returns:
        A new (H, W, 3) uint8 image.
    """
    H, W = view.height, view.width
    top, horizon = sky
    t, alpha = _buffer("t", (H, W)), _buffer("alpha", (H, W))
    np.negative(sin_down, out=t)
    np.clip(t, 0.0, 1.0, out=t)
    np.sqrt(t, out=t)
    # signed distance in pixels to the horizon line, positive on the ground side; the line is where the viewing
    # ray is horizontal, (K^-T R[:, 1]) . (x, y, 1) = 0
    f, cx, cy = view.focal, view.K[0, 2], view.K[1, 2]
    down = view.R[:, 1]
    line = np.array([down[0] / f, down[1] / f, down[2] - down[0] * cx / f - down[1] * cy / f])
    line /= max(math.hypot(line[0], line[1]), 1e-12)
    xs = (np.float32(line[0]) * np.arange(W, dtype=np.float32))[None, :]
    ys = (np.float32(line[1]) * np.arange(H, dtype=np.float32) + np.float32(line[2] + 0.5))[:, None]
    np.add(xs, ys, out=alpha)
    np.clip(alpha, 0.0, 1.0, out=alpha)  # pixel coverage of the ground
    img = np.empty((H, W, 3), np.uint8)
    a, b = _buffer("a", (H, W)), _buffer("b", (H, W))
    for c in range(3):
        np.multiply(t, np.float32(top[c] - horizon[c]), out=a)
        a += np.float32(horizon[c])
        np.subtract(np.float32(ground[c]), a, out=b)
        b *= alpha
        a += b
        a += np.float32(0.5)
        np.clip(a, 0.0, 255.0, out=a)
        img[..., c] = a
    return img


def ground_haze(image: np.ndarray, ground_y: float, visibility: float, haze, sin_down: np.ndarray) -> None:
    """Fade the ground towards the haze colour with its true per-pixel distance, in place. Call it when the image
    holds only sky, ground and things lying on the ground.

    Args:
        image: (H, W, 3) uint8.
        ground_y: height of the camera above the ground.
        visibility: distance where ~63% of the colour is haze.
        haze: RGB haze colour.
        sin_down: :func:`view_rays` of the view.
    """
    if math.isinf(visibility):
        return
    shape = sin_down.shape
    w = _buffer("w", shape)
    # distance to the ground along the ray is ground_y / sin_down; the weight is 1 - exp(-distance / visibility)
    np.maximum(sin_down, np.float32(1e-6), out=w)
    np.divide(np.float32(-ground_y / visibility), w, out=w)
    np.exp(w, out=w)
    np.subtract(np.float32(1.0), w, out=w)
    w[sin_down <= 0] = 0.0
    a, b = _buffer("a", shape), _buffer("b", shape)
    for c in range(3):
        a[:] = image[..., c]
        np.subtract(np.float32(haze[c]), a, out=b)
        b *= w
        a += b
        a += np.float32(0.5)
        image[..., c] = a


def foliage_texture(rng: np.random.Generator, image: np.ndarray, leaves: np.ndarray, amplitude: float) -> None:
    """Leafy texture on the pixels of ``leaves``, in place: blotches of light and shade a few pixels wide with sharp
    borders in every direction, as the leaves of real trees and bushes give (and line detectors then find many
    short segments on them, which flat polygons do not give).

    Args:
        rng: random generator.
        image: (H, W, 3) uint8 RGB.
        leaves: (H, W) bool, the pixels to texture.
        amplitude: the largest relative change of brightness (0 none).
    """
    rows, cols = np.flatnonzero(leaves.any(1)), np.flatnonzero(leaves.any(0))
    if amplitude <= 0 or len(rows) == 0:
        return
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    h, w = int(y1 - y0), int(x1 - x0)
    scale = float(rng.uniform(3.0, 8.0))  # blotch size in pixels
    coarse = rng.standard_normal((int(h / scale) + 2, int(w / scale) + 2), dtype=np.float32)
    blotch = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
    gain = 1.0 + np.float32(amplitude) * np.tanh(np.float32(3.0) * blotch)  # mostly near +-amplitude: sharp borders
    box = image[y0:y1, x0:x1]
    mask = leaves[y0:y1, x0:x1]
    box[mask] = np.clip(box[mask] * gain[mask][:, None] + 0.5, 0, 255).astype(np.uint8)


def photometric(rng: np.random.Generator, image: np.ndarray, cfg) -> np.ndarray:
    """Camera-like degradations of ``image`` (modified in place): exposure, white balance and tone curve (one
    lookup table), uneven shading and vignetting (one gain map), blur, sensor noise, JPEG.

    Args:
        rng: random generator.
        image: (H, W, 3) uint8 RGB.
        cfg: a :class:`ngp_kornia.training.synth.render_config.RenderConfig`.

    Returns:
        The degraded image (``image`` itself unless a JPEG round trip made a new one).
    """
    H, W = image.shape[:2]
    gain = _uniform(rng, cfg.exposure) * (1.0 + rng.uniform(-cfg.color_balance, cfg.color_balance, 3))
    ramp = np.arange(256, dtype=np.float64)[:, None] / 255.0
    lut = 255.0 * np.clip(ramp * gain, 0.0, 1.0) ** _uniform(rng, cfg.gamma)
    cv2.LUT(image, (lut + 0.5).astype(np.uint8).reshape(1, 256, 3), dst=image)
    amp, v = _uniform(rng, cfg.texture), _uniform(rng, cfg.vignetting)
    blur = rng.random() < cfg.blur_prob
    sigma_blur = _uniform(rng, cfg.blur_sigma)
    sigma = _uniform(rng, cfg.noise)
    if blur:  # the lens first, then the sensor
        cv2.GaussianBlur(image, (0, 0), sigma_blur, dst=image)
    if amp > 0 or v > 0 or sigma > 0:
        shade, tmp = _buffer("shade", (H, W)), _buffer("tmp", (H, W))
        shade.fill(1.0)
        if amp > 0:  # smooth, large-scale unevenness of light and materials
            coarse = rng.standard_normal((H // 48 + 2, W // 48 + 2), dtype=np.float32)
            cv2.resize(coarse, (W, H), dst=tmp, interpolation=cv2.INTER_CUBIC)
            tmp *= np.float32(amp)
            shade += tmp
        if v > 0:
            np.multiply(_vignette((H, W)), np.float32(-0.5 * v), out=tmp)
            tmp += np.float32(1.0)
            shade *= tmp
        # luminance noise, uniform of standard deviation sigma (much cheaper to draw than Gaussian)
        noise = _buffer("noise", (H, W))
        rng.random(dtype=np.float32, out=noise)
        noise -= np.float32(0.5)
        noise *= np.float32(sigma * math.sqrt(12.0))
        a = _buffer("a", (H, W))
        for c in range(3):
            a[:] = image[..., c]
            a *= shade
            a += noise
            a += np.float32(0.5)
            np.clip(a, 0.0, 255.0, out=a)
            image[..., c] = a
    if rng.random() < cfg.jpeg_prob:
        q = int(rng.integers(cfg.jpeg_quality[0], cfg.jpeg_quality[1] + 1))
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, q])
        if ok:
            image = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return image


def _uniform(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])
