"""The light of a rendered scene: sun, fill light, ambient level, haze, and the colours of the sky."""

from __future__ import annotations

import math

import numpy as np

from ngp_kornia.training.synth.scene import Lighting

__all__ = ["scene_lighting"]


def _uniform(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


_SKIES = {
    "clear": ((75, 125, 200), (195, 210, 230)),
    "pale": ((120, 160, 210), (215, 222, 232)),
    "dusk": ((80, 95, 150), (235, 190, 150)),
    "overcast": ((170, 175, 185), (215, 218, 222)),
}


def scene_lighting(rng: np.random.Generator, kind: str, cfg) -> tuple[Lighting, tuple[np.ndarray, ...]]:
    """Lights, haze, and the sky colours (zenith, horizon) of a scene of ``kind``, drawn with ``rng`` within the
    ranges of ``cfg`` (a :class:`~ngp_kornia.training.synth.render_config.RenderConfig`)."""
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
