"""One-call calibration: ``ngp_kornia.calibrate(image)``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.io import as_batch
from ngp_kornia.models import Calibration, NeuralGeometricParser, ParserConfig

__all__ = ["WEIGHTS", "calibrate", "load_parser"]

#: weight sets ``calibrate`` accepts; "default" is the best one shipped.
WEIGHTS = ("default", "none")


def load_parser(weights: str = "default", config: ParserConfig | None = None) -> NeuralGeometricParser:
    """The parser for a weight set.

    ``"none"`` is the geometric path: uniform zenith scores and frames ranked by the Manhattan score (Eq. 20).
    ``"default"`` is the best path this version ships, which is currently that same geometric path.
    """
    if weights not in WEIGHTS:
        raise ValueError(f"unknown weights {weights!r}; choose one of {', '.join(WEIGHTS)}")
    return NeuralGeometricParser(config)


def calibrate(
    image: str | Path | np.ndarray | Tensor,
    weights: str = "default",
    seed: int = 0,
    config: ParserConfig | None = None,
) -> Calibration:
    """Calibrate a camera from one photo (or a batch) of a man-made scene.

    Args:
        image: a file path, an HxWx3 uint8 RGB array (HxW greyscale, RGBA and uint16 are converted), or a float
            tensor (3, H, W) or (B, 3, H, W) in [0, 1] on any device.
        weights: ``"default"`` (the best path shipped) or ``"none"`` (the untrained geometric path).
        seed: seed of the random candidate sampling; the same input and seed give the same result.
        config: pipeline settings (:class:`ngp_kornia.models.ParserConfig`).

    Returns:
        a :class:`Calibration` in the input's pixels: ``K``, ``R``, ``focal``, ``fov_v``, ``fov_h``, ``pitch``,
        ``roll``, ``yaw``, ``up``, ``zenith``, ``horizon``, ``vps``, ``score``, ``valid``; batched (leading dim B) for
        batched tensor input. Pixels: x right, y down, origin at the centre of the top-left pixel. Camera: x right,
        y down, z forward. Pitch > 0 looks up; roll > 0 when the scene's up leans right in the image. Degrees.

    Raises:
        ImageError: unreadable, truncated, too small (< 32 px) or NaN input; the message says what to fix.
        TypeError: an input type or dtype that is not supported.

    Example:
        >>> cal = calibrate(torch.rand(3, 64, 64))
        >>> sorted(cal.to_dict())[:4]
        ['K', 'R', 'focal', 'fov_h']
    """
    batch, batched = as_batch(image)
    cfg = replace(config or ParserConfig(), seed=seed)
    parser = load_parser(weights, cfg).to(batch.device)
    with torch.no_grad():
        result = parser(batch)
    return result if batched else result[0]
