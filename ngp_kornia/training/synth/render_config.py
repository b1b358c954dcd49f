"""What the renderer draws: :class:`RenderConfig` (scene kinds, camera ranges, clutter, the hard cases, camera
imperfections, textures), checked on construction, and :func:`config_spec`, the settings that change a render (the
training cache's key). :mod:`ngp_kornia.training.synth.render` draws from it.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, field, fields

__all__ = ["HARD_DEFAULTS", "IMPERFECTION_DEFAULTS", "KINDS", "TEXTURE_DEFAULTS", "RenderConfig", "config_spec"]


KINDS = ("street", "indoor", "atlanta")


def _check_range(name: str, r, lo: float = -math.inf, hi: float = math.inf) -> None:
    if len(r) != 2 or not (lo <= r[0] <= r[1] <= hi):
        raise ValueError(f"{name} must be a (min, max) range within [{lo}, {hi}], got {r}")


def _check_numbers(config: RenderConfig) -> None:
    """Numbers where numbers are meant: NaN passes every range check, true counts as 1, infinity never ends."""
    for f in fields(config):
        value = getattr(config, f.name)
        items = value.values() if isinstance(value, dict) else value if isinstance(value, tuple | list) else [value]
        finite = all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) for v in items)
        if f.name not in ("antialias", "photometric") and not finite:
            raise ValueError(f"{f.name} must hold finite numbers (not NaN, infinity or true/false), got {value!r}")


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
        centre_std: camera imperfection, standard deviation of the principal point's offset from the image
            centre along each axis, as a fraction of the image height (Gaussian, clipped at 3 standard deviations).
            Real cameras rarely have it exactly at the centre; the label's ``K`` carries the true one, so the
            horizon is measured against it while pitch and roll (from ``R``) do not depend on it.
        foliage: texture, the largest relative change of brightness of the leafy texture laid on trees, bushes and
            plants (:func:`~ngp_kornia.training.synth.pixels.foliage_texture`; its amplitude is drawn in
            ``[foliage / 2, foliage]``); 0 leaves them as flat polygons.
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
    centre_std: float = 0.0
    radial_distortion: float = 0.0
    k1_range: tuple[float, float] = (0.0, 0.0)
    foliage: float = 0.0

    def __post_init__(self) -> None:
        _check_numbers(self)
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
        if not (isinstance(self.centre_std, int | float) and 0.0 <= self.centre_std <= 0.25):
            raise ValueError(f"centre_std must be a fraction of the image height in [0, 0.25], "
                             f"got {self.centre_std!r}")
        if not (isinstance(self.radial_distortion, int | float) and 0.0 <= self.radial_distortion <= 0.1):
            raise ValueError(f"radial_distortion must be a standard deviation of k1 in [0, 0.1], "
                             f"got {self.radial_distortion!r}")
        _check_range("k1_range", self.k1_range, -0.5, 0.5)
        self.k1_range = (float(self.k1_range[0]), float(self.k1_range[1]))
        if self.radial_distortion > 0 and tuple(self.k1_range) != (0.0, 0.0):
            raise ValueError("give radial_distortion (a Gaussian k1) or k1_range (a uniform one), not both")
        if not (isinstance(self.foliage, int | float) and 0.0 <= self.foliage <= 1.0):
            raise ValueError(f"foliage must be a relative change of brightness in [0, 1], got {self.foliage!r}")
        if not 0.0 <= self.fronto_prob <= 1.0:
            raise ValueError(f"fronto_prob must be a probability, got {self.fronto_prob}")
        unknown = set(self.kinds) - set(KINDS)
        if unknown:
            raise ValueError(f"unknown scene kinds {sorted(unknown)}; choose from {KINDS}")
        if any(p < 0 for p in self.kinds.values()) or sum(self.kinds.values()) <= 0:
            raise ValueError(f"kinds must hold non-negative probabilities with a positive sum, got {self.kinds}")


HARD_DEFAULTS = {"stairs": 0.0, "billboards": 0.0, "fronto_prob": 0.0, "fronto_jitter": 3.0}
"""The hard-case options of :class:`RenderConfig` and their defaults (off)."""
IMPERFECTION_DEFAULTS = {"centre_std": 0.0, "radial_distortion": 0.0, "k1_range": (0.0, 0.0)}
"""The camera-imperfection options of :class:`RenderConfig` and their defaults (off: an ideal pinhole)."""
TEXTURE_DEFAULTS = {"foliage": 0.0}
"""The texture options of :class:`RenderConfig` and their defaults (off: flat polygons)."""


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
    defaults = {**HARD_DEFAULTS, **IMPERFECTION_DEFAULTS, **TEXTURE_DEFAULTS}
    return {k: v for k, v in spec.items() if not (k in defaults and v == defaults[k])}
