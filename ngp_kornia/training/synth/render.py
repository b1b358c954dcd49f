"""Procedural renderer of man-made scenes with exact ground-truth calibration: the training data of the project and
its built-in demo.

:func:`render_scene` draws, from one integer seed, a photo-like image of a street crossing, a furnished room or an
Atlanta-world plaza seen by a random pinhole camera, and returns it with the camera's ground truth (intrinsics,
rotation, pitch / roll / yaw, field of view, zenith, horizon, Manhattan vanishing points), computed with the
functions of :mod:`ngp_kornia.geometry.camera` so it follows the project's conventions exactly:

* the principal point is the image centre ``((W - 1) / 2, (H - 1) / 2)`` unless
  :attr:`RenderConfig.principal_point_std` moves it (the label's ``K`` is always the true one), pixels have their
  origin at the centre of the top-left pixel, square pixels, no distortion;
* ``R = rotation_from_angles(pitch, roll, yaw)`` maps world to camera; the camera stands at the world origin and
  the ground is the plane ``y = camera_height`` (world y points down);
* ``vps[i] = K @ R[:, i]`` normalised: the vanishing points of the world axes, row 1 the vertical. Streets and
  rooms are aligned with the world axes; in Atlanta scenes the world axes are the frame of the dominant block group
  (the largest block, straight ahead of the camera), other groups are turned by ``frames`` degrees of yaw.

:func:`render_dataset` writes a folder of images plus ``ground_truth.json``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry.camera import (
    focal_from_fov,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    rotation_from_angles,
    up_from_rotation,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.training.synth.hard import Additions
from ngp_kornia.training.synth.interior import make_room
from ngp_kornia.training.synth.layouts import make_atlanta, make_street
from ngp_kornia.training.synth.painter import Canvas, PinholeView
from ngp_kornia.training.synth.pixels import ground_haze, photometric, sky_and_ground, view_rays
from ngp_kornia.training.synth.scene import Lighting, Scene, draw_ground, draw_objects

__all__ = [
    "HARD_DEFAULTS",
    "IMPERFECTION_DEFAULTS",
    "KINDS",
    "RenderConfig",
    "RenderedScene",
    "camera_ground_truth",
    "config_spec",
    "render_dataset",
    "render_scene",
]

KINDS = ("street", "indoor", "atlanta")


def _check_range(name: str, r, lo: float = -math.inf, hi: float = math.inf) -> None:
    if len(r) != 2 or not (lo <= r[0] <= r[1] <= hi):
        raise ValueError(f"{name} must be a (min, max) range within [{lo}, {hi}], got {r}")


@dataclass
class RenderConfig:
    """What :func:`render_scene` draws. Ranges are ``(min, max)``, sampled uniformly; angles in degrees.

    Attributes:
        fov_v: vertical field of view.
        pitch: camera pitch (> 0 looking up).
        roll: camera roll.
        yaw: camera yaw (heading) in the world.
        camera_height: outdoor camera height above the road, metres.
        indoor_camera_height: indoor camera height above the floor.
        kinds: relative probabilities of the scene kinds ``street``, ``indoor``, ``atlanta``.
        clutter: amount of cars, trees, people, furniture: 0 none, 1 normal, 2 busy.
        antialias: anti-aliased edges.
        photometric: apply the photometric effects below at all (False: clean renders).
        exposure: exposure gain.
        gamma: tone curve exponent.
        color_balance: per-channel gain spread (white balance error).
        texture: amplitude of smooth multiplicative shading noise (uneven light and materials).
        noise: standard deviation of the sensor noise, in 8-bit levels.
        blur_prob: probability of a Gaussian blur.
        blur_sigma: its standard deviation in pixels.
        jpeg_prob: probability of a JPEG round trip.
        jpeg_quality: JPEG quality.
        vignetting: darkening of the corners (0 none, 1 black).
        haze_prob: probability of aerial perspective outdoors.
        visibility: distance in metres where ~63% of the colour is haze.
        overcast_prob: probability of a grey sky and soft light outdoors.
        stairs: hard case, mean number of flights of stairs with handrails per outdoor scene (sloped lines).
        billboards: hard case, mean number of billboards turned off the scene's axes per outdoor scene (a false
            horizontal vanishing point).
        fronto_prob: hard case, probability that an outdoor camera faces a facade square on (no finite horizontal
            vanishing point): its yaw is moved to the nearest facade normal, plus ``fronto_jitter``.
        fronto_jitter: standard deviation of the yaw around the facade normal.
        principal_point_std: camera imperfection, standard deviation of the principal point's offset from the image
            centre along each axis, as a fraction of the image height (Gaussian, clipped at 3 standard deviations).
            Real cameras rarely have it exactly at the centre; the label's ``K`` carries the true one, so the
            horizon is measured against it while pitch and roll (from ``R``) do not depend on it.
        radial_distortion: camera imperfection, standard deviation of the radial distortion coefficient ``k1``
            (Gaussian, clipped at 3 standard deviations) of the division model ``x_u = x_d / (1 + k1 |x_d|^2)``,
            ``x`` the ray's coordinates ``(p - c) / f`` about the principal point: the pinhole image, drawn with a
            margin, is warped so that straight lines bend (``k1 < 0`` barrel). The ground truth stays the pinhole
            camera's (``K``, ``R``); the label also carries ``k1``.
        k1_range: camera imperfection, ``(min, max)`` of a uniformly drawn ``k1`` of the same model instead of the
            Gaussian one (``(0, 0)``: off); ``(-0.3, 0)`` is barrel distortion up to a strong wide-angle lens.

    The hard cases and the camera imperfections are off by default and drawn from random streams of their own, after
    the scene: with all of them off a render is the same, bit for bit, as before they existed (:data:`HARD_DEFAULTS`,
    :data:`IMPERFECTION_DEFAULTS`).
    """

    fov_v: tuple[float, float] = (40.0, 80.0)
    pitch: tuple[float, float] = (-30.0, 40.0)
    roll: tuple[float, float] = (-20.0, 20.0)
    yaw: tuple[float, float] = (-180.0, 180.0)
    camera_height: tuple[float, float] = (1.2, 3.0)
    indoor_camera_height: tuple[float, float] = (1.0, 1.8)
    kinds: dict[str, float] = field(default_factory=lambda: {"street": 0.5, "indoor": 0.3, "atlanta": 0.2})
    clutter: float = 1.0
    antialias: bool = True
    photometric: bool = True
    exposure: tuple[float, float] = (0.8, 1.25)
    gamma: tuple[float, float] = (0.85, 1.2)
    color_balance: float = 0.06
    texture: tuple[float, float] = (0.0, 0.04)
    noise: tuple[float, float] = (0.0, 4.0)
    blur_prob: float = 0.3
    blur_sigma: tuple[float, float] = (0.3, 1.0)
    jpeg_prob: float = 0.5
    jpeg_quality: tuple[int, int] = (40, 95)
    vignetting: tuple[float, float] = (0.0, 0.35)
    haze_prob: float = 0.6
    visibility: tuple[float, float] = (250.0, 1500.0)
    overcast_prob: float = 0.3
    stairs: float = 0.0
    billboards: float = 0.0
    fronto_prob: float = 0.0
    fronto_jitter: float = 3.0
    principal_point_std: float = 0.0
    radial_distortion: float = 0.0
    k1_range: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        _check_range("fov_v", self.fov_v, 1.0, 179.0)
        _check_range("pitch", self.pitch, -89.0, 89.0)
        _check_range("roll", self.roll, -180.0, 180.0)
        _check_range("yaw", self.yaw)
        _check_range("camera_height", self.camera_height, 0.05)
        _check_range("indoor_camera_height", self.indoor_camera_height, 0.05, 3.0)
        for name in ("exposure", "gamma", "blur_sigma", "visibility"):
            _check_range(name, getattr(self, name), 1e-6)
        for name in ("texture", "noise", "vignetting"):
            _check_range(name, getattr(self, name), 0.0)
        _check_range("jpeg_quality", self.jpeg_quality, 1, 100)
        for name in ("blur_prob", "jpeg_prob", "haze_prob", "overcast_prob"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be a probability, got {getattr(self, name)}")
        if self.clutter < 0 or self.color_balance < 0:
            raise ValueError("clutter and color_balance must be non-negative")
        if self.stairs < 0 or self.billboards < 0 or self.fronto_jitter < 0:
            raise ValueError("stairs, billboards and fronto_jitter must be non-negative")
        if not (isinstance(self.principal_point_std, int | float) and 0.0 <= self.principal_point_std <= 0.25):
            raise ValueError(f"principal_point_std must be a fraction of the image height in [0, 0.25], "
                             f"got {self.principal_point_std!r}")
        if not (isinstance(self.radial_distortion, int | float) and 0.0 <= self.radial_distortion <= 0.1):
            raise ValueError(f"radial_distortion must be a standard deviation of k1 in [0, 0.1], "
                             f"got {self.radial_distortion!r}")
        _check_range("k1_range", self.k1_range, -0.5, 0.5)
        self.k1_range = (float(self.k1_range[0]), float(self.k1_range[1]))
        if self.radial_distortion > 0 and tuple(self.k1_range) != (0.0, 0.0):
            raise ValueError("give radial_distortion (a Gaussian k1) or k1_range (a uniform one), not both")
        if not 0.0 <= self.fronto_prob <= 1.0:
            raise ValueError(f"fronto_prob must be a probability, got {self.fronto_prob}")
        unknown = set(self.kinds) - set(KINDS)
        if unknown:
            raise ValueError(f"unknown scene kinds {sorted(unknown)}; choose from {KINDS}")
        if any(p < 0 for p in self.kinds.values()) or sum(self.kinds.values()) <= 0:
            raise ValueError(f"kinds must hold non-negative probabilities with a positive sum, got {self.kinds}")


@dataclass
class RenderedScene:
    """A rendered image and its exact ground truth (torch float64; angles in degrees, lengths in pixels).

    Attributes:
        image: (H, W, 3) uint8 RGB.
        K: (3, 3) the true intrinsics (principal point at the image centre unless the config moves it).
        R: (3, 3) world-to-camera rotation.
        focal: focal length.
        fov_v: vertical field of view.
        fov_h: horizontal field of view.
        pitch: pitch.
        roll: roll.
        yaw: yaw (heading in the world frame).
        zenith: (3,) zenith VP ``K @ up`` in homogeneous pixels.
        horizon: (3,) horizon line, ``a^2 + b^2 = 1``, ``b >= 0``.
        vps: (3, 3) rows ``K @ R[:, i]`` normalised: the VPs of world x, y (vertical), z.
        seed: the seed it was rendered from.
        kind: ``street``, ``indoor`` or ``atlanta``.
        frames: yaws (degrees) of the block groups in the scene, the ground-truth one (0) first.
        scene: the 3D scene (for checks and debugging).
        k1: the radial distortion coefficient the image was warped with (0: a pinhole image).
    """

    image: np.ndarray
    K: Tensor
    R: Tensor
    focal: Tensor
    fov_v: Tensor
    fov_h: Tensor
    pitch: Tensor
    roll: Tensor
    yaw: Tensor
    zenith: Tensor
    horizon: Tensor
    vps: Tensor
    seed: int
    kind: str
    frames: tuple[float, ...] = (0.0,)
    scene: Scene | None = field(default=None, repr=False)
    k1: float = 0.0

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    def to_dict(self) -> dict:
        """The ground truth as plain JSON-able lists and floats.

        Keys: ``K, R, focal, fov_v, fov_h, pitch, roll, yaw, zenith, horizon, vps, width, height, seed, kind``,
        and ``k1`` when the image was distorted.
        """
        out = {name: getattr(self, name).tolist() for name in ("K", "R", "zenith", "horizon", "vps")}
        for name in ("focal", "fov_v", "fov_h", "pitch", "roll", "yaw"):
            out[name] = float(getattr(self, name))
        out.update(width=self.width, height=self.height, seed=int(self.seed), kind=self.kind)
        if self.k1 != 0.0:
            out["k1"] = float(self.k1)
        return out


HARD_DEFAULTS = {"stairs": 0.0, "billboards": 0.0, "fronto_prob": 0.0, "fronto_jitter": 3.0}
"""The hard-case options of :class:`RenderConfig` and their defaults (off)."""

IMPERFECTION_DEFAULTS = {"principal_point_std": 0.0, "radial_distortion": 0.0, "k1_range": (0.0, 0.0)}
"""The camera-imperfection options of :class:`RenderConfig` and their defaults (off: an ideal pinhole)."""


def config_spec(config: RenderConfig) -> dict:
    """The settings of a config that change its renders, as a plain dict: every field, less the hard-case options
    left at their defaults (so the digest of a config from before they existed does not change).

    Example:
        >>> "stairs" in config_spec(RenderConfig()), config_spec(RenderConfig(stairs=1.0))["stairs"]
        (False, 1.0)
    """
    spec = asdict(config)
    if config.fronto_prob == 0.0:
        spec.pop("fronto_jitter")  # has no effect then
    defaults = {**HARD_DEFAULTS, **IMPERFECTION_DEFAULTS}
    return {k: v for k, v in spec.items() if not (k in defaults and v == defaults[k])}


def camera_ground_truth(fov_v: float, pitch: float, roll: float, yaw: float, size: tuple[int, int],
                        offset: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The calibration ground truth of a camera, with the project's geometry functions.

    Args:
        fov_v: vertical field of view (degrees).
        pitch: pitch (degrees).
        roll: roll (degrees).
        yaw: yaw (degrees).
        size: image ``(W, H)``.
        offset: the principal point's offset ``(dx, dy)`` from the image centre, pixels.

    Returns:
        A dict of float64 tensors: ``K, R, focal, fov_v, fov_h, pitch, roll, yaw, zenith, horizon, vps``.

    Example:
        >>> gt = camera_ground_truth(60.0, 0.0, 0.0, 0.0, (640, 480))
        >>> gt["horizon"].tolist()  # level camera: the horizon is the middle row
        [0.0, 1.0, -239.5]
    """
    W, H = size
    t = {k: torch.tensor([float(v)], dtype=torch.float64) for k, v in
         dict(fov_v=fov_v, pitch=pitch, roll=roll, yaw=yaw).items()}
    focal = focal_from_fov(t["fov_v"], H)
    center = image_center(H, W, like=focal)
    if offset[0] != 0.0 or offset[1] != 0.0:
        center = center + torch.tensor([float(offset[0]), float(offset[1])], dtype=center.dtype)
    K = intrinsics_matrix(focal, center)
    R = rotation_from_angles(t["pitch"], t["roll"], t["yaw"])
    zenith = zenith_from_up(K, up_from_rotation(R))
    return {
        "K": K[0], "R": R[0], "focal": focal[0], "fov_v": t["fov_v"][0], "fov_h": fov_from_focal(focal, W)[0],
        "pitch": t["pitch"][0], "roll": t["roll"][0], "yaw": t["yaw"][0], "zenith": zenith[0],
        "horizon": horizon_from_zenith(K, zenith)[0], "vps": vanishing_points_from_rotation(K, R)[0],
    }


def _check_size(size) -> tuple[int, int]:
    if len(size) != 2 or any(int(s) != s or s < 8 for s in size):
        raise ValueError(f"size must be (W, H) with integers >= 8, got {size}")
    return int(size[0]), int(size[1])


def _uniform(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def render_scene(seed: int, size: tuple[int, int] = (640, 480), config: RenderConfig | None = None) -> RenderedScene:
    """Render one random scene with its exact calibration ground truth, deterministically from ``seed``.

    Args:
        seed: non-negative integer; the same seed, size and config always give the same image.
        size: image ``(W, H)``.
        config: what to draw; :class:`RenderConfig` defaults when None.

    Returns:
        The image and its ground truth.

    Example:
        >>> r = render_scene(3, (64, 48))
        >>> r.image.shape, r.image.dtype, tuple(r.K.shape), r.K[0, 2].item()
        ((48, 64, 3), dtype('uint8'), (3, 3), 31.5)
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    W, H = _check_size(size)
    cfg = RenderConfig() if config is None else config
    # the hard cases draw from a fourth stream, the camera imperfections from a fifth: the first three are those of
    # spawn(3), as before they existed (a SeedSequence's i-th child does not depend on how many are spawned)
    cam_rng, scene_rng, photo_rng, hard_rng, lens_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(5))
    names = [k for k in KINDS if cfg.kinds.get(k, 0.0) > 0]
    p = np.array([cfg.kinds[k] for k in names])
    kind = names[int(cam_rng.choice(len(names), p=p / p.sum()))]
    fov_v, pitch, roll, yaw = (_uniform(cam_rng, r) for r in (cfg.fov_v, cfg.pitch, cfg.roll, cfg.yaw))
    cam_h = _uniform(cam_rng, cfg.indoor_camera_height if kind == "indoor" else cfg.camera_height)
    if kind != "indoor" and cfg.fronto_prob > 0 and hard_rng.random() < cfg.fronto_prob:
        yaw = _fronto_yaw(hard_rng, kind, yaw, cfg.fronto_jitter)
    offset = (0.0, 0.0)
    if cfg.principal_point_std > 0:
        offset = tuple(float(v) for v in np.clip(lens_rng.normal(0.0, 1.0, 2), -3, 3) * cfg.principal_point_std * H)
    gt = camera_ground_truth(fov_v, pitch, roll, yaw, (W, H), offset)

    k1 = float(np.clip(lens_rng.normal(), -3, 3) * cfg.radial_distortion) if cfg.radial_distortion > 0 else 0.0
    if tuple(cfg.k1_range) != (0.0, 0.0):
        k1 = _uniform(lens_rng, cfg.k1_range)
    source = _undistorted_coordinates(gt["K"].numpy(), k1, W, H) if k1 != 0.0 else None
    margin = 0 if source is None else _margin(source, W, H)
    K = gt["K"].numpy() + np.array([[0, 0, margin], [0, 0, margin], [0, 0, 0]])
    view = PinholeView(K, gt["R"].numpy(), np.zeros(3), W + 2 * margin, H + 2 * margin)
    add = Additions(hard_rng, cfg.stairs, cfg.billboards) if cfg.stairs > 0 or cfg.billboards > 0 else None
    if kind == "street":
        scene = make_street(scene_rng, cam_h, cfg.clutter, view=view, additions=add)
    elif kind == "indoor":
        scene = make_room(scene_rng, cam_h, cfg.clutter, view_yaw=yaw)
    else:
        scene = make_atlanta(scene_rng, cam_h, cfg.clutter, view_yaw=yaw, additions=add)
    image = _paint(view, scene, *_lighting(photo_rng, kind, cfg), cfg.antialias)
    if source is not None:
        image = cv2.remap(image, *(source + margin), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if cfg.photometric:
        image = photometric(photo_rng, image, cfg)
    return RenderedScene(image=image, seed=int(seed), kind=kind, frames=tuple(scene.frames), scene=scene, k1=k1, **gt)


def _paint(view: PinholeView, scene: Scene, light: Lighting, sky: tuple, antialias: bool) -> np.ndarray:
    """The pinhole image of a scene: sky, ground, haze and objects."""
    if scene.ground_color is None:  # indoors: the room hides everything, only seams between faces may show
        image = np.full((view.height, view.width, 3), 150, np.uint8)
    else:
        sin_down = view_rays(view)
        ground = scene.ground_color * light.factor(np.array([0.0, -1.0, 0.0]))
        image = sky_and_ground(view, ground, sky, sin_down)
    canvas = Canvas(view, image, antialias=antialias)
    draw_ground(canvas, scene, light)
    if scene.ground_color is not None:
        ground_haze(image, scene.ground_y, light.visibility, light.haze, sin_down)
    draw_objects(canvas, scene, light)
    return image


def _undistorted_coordinates(K: np.ndarray, k1: float, W: int, H: int) -> np.ndarray:
    """(2, H, W) float32: for every pixel of the distorted image, where its ray meets the pinhole image (the
    division model ``x_u = x_d / (1 + k1 |x_d|^2)``)."""
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    xd = (np.arange(W, dtype=np.float64)[None, :] - cx) / f + np.zeros((H, 1))
    yd = (np.arange(H, dtype=np.float64)[:, None] - cy) / f + np.zeros((1, W))
    scale = 1.0 + k1 * (xd * xd + yd * yd)
    return np.stack([xd / scale * f + cx, yd / scale * f + cy]).astype(np.float32)


def _margin(source: np.ndarray, W: int, H: int) -> int:
    """Pixels to draw beyond each border so that every source coordinate lies inside the pinhole image."""
    over = max(-source.min(), source[0].max() - (W - 1), source[1].max() - (H - 1), 0.0)
    return int(math.ceil(over)) + 2


def _fronto_yaw(rng: np.random.Generator, kind: str, yaw: float, jitter: float) -> float:
    """A yaw facing a facade square on: on a street the facades along the main road (normals along world x), in a
    plaza the dominant block's nearest side; plus Gaussian jitter."""
    step = 180.0 if kind == "street" else 90.0
    base = 90.0 + step * round((yaw - 90.0) / step)
    return float(base + rng.normal(0.0, jitter))


_SKIES = {
    "clear": ((75, 125, 200), (195, 210, 230)),
    "pale": ((120, 160, 210), (215, 222, 232)),
    "dusk": ((80, 95, 150), (235, 190, 150)),
    "overcast": ((170, 175, 185), (215, 218, 222)),
}


def _lighting(rng: np.random.Generator, kind: str, cfg: RenderConfig) -> tuple[Lighting, tuple[np.ndarray, ...]]:
    """Lights, haze, and the sky colours (zenith, horizon)."""
    overcast = kind != "indoor" and rng.random() < cfg.overcast_prob
    sky_name = "overcast" if overcast else ["clear", "pale", "dusk"][rng.choice(3, p=[0.5, 0.35, 0.15])]
    top, horizon = (np.asarray(c, float) + rng.normal(0, 6, 3) for c in _SKIES[sky_name])
    if kind == "indoor":
        sun = np.array([rng.normal(0, 0.3), -1.0, rng.normal(0, 0.3)])
        fill = np.array([math.cos(a := rng.uniform(0, 2 * math.pi)), -0.2, math.sin(a)])
        light = Lighting(ambient=rng.uniform(0.55, 0.75), sun_dir=sun / np.linalg.norm(sun), sun=rng.uniform(0.15, 0.3),
                         fill_dir=fill / np.linalg.norm(fill), fill=rng.uniform(0.1, 0.3))
        return light, (top, horizon)
    az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(15, 70))
    sun = np.array([math.cos(el) * math.sin(az), -math.sin(el), math.cos(el) * math.cos(az)])
    fill = np.array([-sun[0], -0.3, -sun[2]])
    light = Lighting(
        ambient=rng.uniform(0.75, 0.9) if overcast else rng.uniform(0.45, 0.62),
        sun_dir=sun, sun=rng.uniform(0.1, 0.2) if overcast else rng.uniform(0.35, 0.6),
        fill_dir=fill / np.linalg.norm(fill), fill=rng.uniform(0.05, 0.15),
        haze=horizon.copy(),
        visibility=_uniform(rng, cfg.visibility) if rng.random() < cfg.haze_prob else math.inf,
    )
    return light, (top, horizon)


def render_dataset(outdir: str | Path, count: int, seed: int = 0, size: tuple[int, int] = (640, 480),
                   config: RenderConfig | None = None, ext: str = "png",
                   progress: Callable[[int], object] | None = None) -> list[dict]:
    """Render ``count`` scenes into ``outdir`` as ``000000.png``... plus ``ground_truth.json``.

    Image ``i`` is rendered from its own seed, derived from ``(seed, i)``, so datasets of different seeds do not
    overlap and a prefix of a dataset does not depend on ``count``; each record stores its seed, so
    ``render_scene(record["seed"], size, config)`` re-renders it.

    Args:
        outdir: output folder (created).
        count: number of images.
        seed: dataset seed.
        size: image ``(W, H)``.
        config: render settings.
        ext: ``png`` (lossless) or ``jpg``.
        progress: called with 1 after each image is written (e.g. a progress bar's ``update``).

    Returns:
        The records written to ``ground_truth.json``: :meth:`RenderedScene.to_dict` plus ``image`` (file name).
    """
    if count < 0 or seed < 0:
        raise ValueError(f"count and seed must be non-negative, got {count} and {seed}")
    if ext not in ("png", "jpg"):
        raise ValueError(f"ext must be 'png' or 'jpg', got {ext!r}")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for i in range(count):
        s = int(np.random.SeedSequence([int(seed), i]).generate_state(1)[0] >> 1)
        r = render_scene(s, size, config)
        name = f"{i:06d}.{ext}"
        if not cv2.imwrite(str(out / name), r.image[..., ::-1]):
            raise OSError(f"could not write {out / name}")
        records.append({"image": name, **r.to_dict()})
        if progress is not None:
            progress(1)
    (out / "ground_truth.json").write_text(json.dumps(records, indent=1))
    return records
