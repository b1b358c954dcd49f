"""Images without man-made structure, drawn procedurally: the negatives that teach the parser's orientation and
structure check (:mod:`ngp_kornia.nets.upright`) what an image it cannot calibrate looks like.

Each kind imitates something a user may hand the parser by mistake or that fills a photo without any building:
sensor or file noise, clouds, water, foliage, sand and stone. None holds straight edges in three directions, so no
answer about a camera can rest on it.

Example:
    >>> img = structureless_image(0, (160, 120), "clouds")
    >>> img.shape, img.dtype
    ((120, 160, 3), dtype('uint8'))
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["KINDS", "structureless_image"]


def _palette(rng: np.random.Generator, base: tuple[float, float, float], spread: float = 25.0) -> np.ndarray:
    return np.clip(np.asarray(base, float) + rng.normal(0, spread, 3), 0, 255)


def _fractal(rng: np.random.Generator, h: int, w: int, beta: float) -> np.ndarray:
    """Noise with a ``1 / f**beta`` amplitude spectrum, scaled to [0, 1]."""
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.rfftfreq(w)[None, :]
    f = np.sqrt(fx**2 + fy**2)
    f[0, 0] = 1.0
    spectrum = (rng.normal(size=f.shape) + 1j * rng.normal(size=f.shape)) / f**beta
    spectrum[0, 0] = 0.0
    field = np.fft.irfft2(spectrum, s=(h, w))
    return (field - field.min()) / max(float(np.ptp(field)), 1e-9)


def _blend(t: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    return low + t[..., None] * (high - low)


def _noise(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    grey = rng.random() < 0.4
    if rng.random() < 0.5:
        img = rng.random((h, w, 1 if grey else 3)) * 255.0
    else:
        img = rng.normal(rng.uniform(60, 190), rng.uniform(10, 70), (h, w, 1 if grey else 3))
    if rng.random() < 0.4:  # smoothed a little, as a compressed or resized noise image is
        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), rng.uniform(0.5, 2.5)).reshape(h, w, -1)
    return np.broadcast_to(img, (h, w, 3))


def _clouds(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    t = _fractal(rng, h, w, rng.uniform(1.3, 2.2)) ** rng.uniform(0.7, 1.8)
    sky, cloud = _palette(rng, (95, 140, 205), 30), _palette(rng, (235, 235, 238), 12)
    return _blend(t, sky, cloud)


def _water(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(float)
    t = 0.6 * _fractal(rng, h, w, rng.uniform(1.0, 1.8))
    for _ in range(rng.integers(3, 9)):
        a, k = rng.uniform(0, np.pi), rng.uniform(0.03, 0.4)
        t = t + rng.uniform(0.05, 0.2) * np.sin(k * (np.cos(a) * x + np.sin(a) * y) + rng.uniform(0, 6.3))
    t = (t - t.min()) / max(float(np.ptp(t)), 1e-9)
    return _blend(t, _palette(rng, (20, 60, 90), 20), _palette(rng, (120, 170, 190), 25))


def _foliage(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    img = np.empty((h, w, 3), np.float32)
    img[:] = _palette(rng, (40, 70, 30), 15)
    scale = rng.uniform(0.01, 0.05) * max(h, w)
    for _ in range(int(rng.uniform(1.5, 4.0) * h * w / scale**2)):
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        axes = (max(1, int(scale * rng.uniform(0.3, 1.0))), max(1, int(scale * rng.uniform(0.15, 0.5))))
        colour = _palette(rng, (70, 115, 45), 30).tolist()
        cv2.ellipse(img, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA)
    return img + rng.normal(0, 6, img.shape)


def _stone(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Sand, gravel or marble: fractal grain, sometimes veined by a turbulent sine."""
    t = _fractal(rng, h, w, rng.uniform(0.4, 1.4))
    if rng.random() < 0.5:
        y, x = np.mgrid[0:h, 0:w].astype(float)
        a = rng.uniform(0, np.pi)
        veins = np.sin(0.02 * (np.cos(a) * x + np.sin(a) * y) + 12.0 * _fractal(rng, h, w, 2.0))
        t = 0.5 * t + 0.5 * (veins + 1) / 2
    return _blend(t, _palette(rng, (120, 105, 85), 35), _palette(rng, (215, 200, 175), 25))


#: the kinds of :func:`structureless_image`
KINDS = ("noise", "clouds", "water", "foliage", "stone")
_MAKERS = {"noise": _noise, "clouds": _clouds, "water": _water, "foliage": _foliage, "stone": _stone}


def structureless_image(seed: int, size: tuple[int, int] = (640, 480), kind: str | None = None) -> np.ndarray:
    """An (H, W, 3) uint8 RGB image of ``kind`` (one of :data:`KINDS`; None draws one from the seed)."""
    rng = np.random.default_rng(seed)
    kind = KINDS[int(rng.integers(len(KINDS)))] if kind is None else kind
    if kind not in _MAKERS:
        raise ValueError(f"unknown structure-free kind {kind!r}; choose one of {', '.join(KINDS)}")
    w, h = int(size[0]), int(size[1])
    return np.clip(_MAKERS[kind](rng, h, w), 0, 255).astype(np.uint8)
