"""One-call calibration: ``ngp_kornia.calibrate(image)``."""

from __future__ import annotations

from collections.abc import Sequence
from copy import deepcopy
from dataclasses import replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from ngp_kornia.detect import detect_segments_gray, pad_segments
from ngp_kornia.exif import exif_focal
from ngp_kornia.io import as_batch, read_rgb
from ngp_kornia.models import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.models.weights import load_network, network_name, shipped_weights

__all__ = ["DEFAULT_WEIGHTS", "WEIGHTS", "calibrate", "load_parser"]

#: weight sets ``calibrate`` accepts by name; paths to weights files (``.pt``) work too.
WEIGHTS = ("default", "none", "zsnet", "fsnet", "full")
#: what "default" means: the most accurate path this version ships (see BENCHMARKS.md).
DEFAULT_WEIGHTS = "fsnet"
#: the shipped networks each named weight set uses
_NAMED = {"none": (), "zsnet": ("zsnet",), "fsnet": ("fsnet",), "full": ("zsnet", "fsnet")}


@lru_cache(maxsize=8)
def _network(path: str) -> torch.nn.Module:
    return load_network(path, network_name(path))


def _networks(weights: str | Path | Sequence[str | Path]) -> list[torch.nn.Module]:
    if isinstance(weights, str) and weights == "default":
        weights = DEFAULT_WEIGHTS
    if isinstance(weights, str) and weights in _NAMED:
        return [_network(str(shipped_weights(name))) for name in _NAMED[weights]]
    paths = [weights] if isinstance(weights, (str, Path)) else list(weights)
    if not paths or not all(isinstance(p, Path) or str(p).endswith(".pt") for p in paths):
        raise ValueError(
            f"unknown weights {weights!r}; choose one of {', '.join(WEIGHTS)} or give paths to .pt weights files"
        )
    return [_network(str(p)) for p in paths]


def load_parser(
    weights: str | Path | Sequence[str | Path] = "default", config: ParserConfig | None = None
) -> NeuralGeometricParser:
    """The parser for a weight set.

    ``"none"`` is the geometric path: uniform zenith scores and frames ranked by the Manhattan score (Eq. 21).
    ``"zsnet"`` scores the zenith candidates with the shipped ZSNet, ``"fsnet"`` rescores the best frames with the
    shipped FSNet, ``"full"`` uses both (the paper's parser). ``"default"`` is :data:`DEFAULT_WEIGHTS`. A path (or
    a list of paths) loads weights files written by ``ngp-train export``: a ZSNet file, an FSNet file, or one of each.

    The networks are the caller's own copies, in eval mode: training them (as a layer of a larger model) or moving
    them does not change what :func:`calibrate` computes.
    """
    return _parser(weights, config, copy=True)


def _parser(weights, config: ParserConfig | None, copy: bool) -> NeuralGeometricParser:
    nets = {type(net).__name__: deepcopy(net) if copy else net for net in _networks(weights)}
    return NeuralGeometricParser(config, zsnet=nets.get("ZSNet"), fsnet=nets.get("FSNet"))


def segments_of_rgb(rgb: np.ndarray, config: ParserConfig) -> tuple[Tensor, Tensor]:
    """LSD segments (1, N, 2, 2) and mask (1, N) of an (H, W, 3) uint8 RGB image, as :func:`calibrate` finds them
    for a file: on the 8-bit grey image, at the config's working size, length limit and count."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return pad_segments([detect_segments_gray(gray, config.working_size, config.min_length, config.max_segments)])


def calibrate(
    image: str | Path | np.ndarray | Tensor,
    weights: str = "default",
    seed: int = 0,
    config: ParserConfig | None = None,
    focal: float | None = None,
    fov_v: float | None = None,
    exif: bool = False,
) -> Calibration:
    """Calibrate a camera from one photo (or a batch) of a man-made scene.

    Args:
        image: a file path, an HxWx3 uint8 RGB array (HxW greyscale, RGBA and uint16 are converted), or a float
            tensor (3, H, W) or (B, 3, H, W) in [0, 1] on any device.
        weights: ``"default"`` (the best path shipped), ``"none"`` (the untrained geometric path), ``"zsnet"`` (zenith
            candidates scored by the shipped ZSNet), ``"fsnet"`` (frames rescored by the shipped FSNet), ``"full"``
            (both), or the path of a weights file (or a list of paths: one ZSNet and one FSNet file).
        seed: seed of the random candidate sampling; the same input and seed give the same result.
        config: pipeline settings (:class:`ngp_kornia.models.ParserConfig`).
        focal: a known focal length in pixels of the input image (a prior; overrides the config's).
        fov_v: a known vertical field of view in degrees (a prior; ``focal`` wins when both are given).
        exif: for a file without ``focal`` / ``fov_v``, use the focal length its EXIF block records
            (``FocalLengthIn35mmFilm``, or ``FocalLength`` with the sensor resolution); no prior when it has none.

    Returns:
        a :class:`Calibration` in the input's pixels: ``K``, ``R``, ``focal``, ``fov_v``, ``fov_h``, ``pitch``,
        ``roll``, ``yaw``, ``up``, ``zenith``, ``horizon``, ``vps``, ``score``, ``valid``, ``confidence`` (the
        probability that the horizon is within 0.02 image heights), ``pitch_std``, ``roll_std``, ``fov_v_std``
        (degrees); batched (leading dim B) for
        batched tensor input. Pixels: x right, y down, origin at the centre of the top-left pixel. Camera: x right,
        y down, z forward. Pitch > 0 looks up; roll > 0 when the scene's up leans right in the image. Degrees.

    Raises:
        ImageError: unreadable, truncated, too small (< 32 px) or NaN input; the message says what to fix.
        WeightsError: a missing, corrupt or mismatched weights file.
        TypeError: an input type or dtype that is not supported.

    Example:
        >>> cal = calibrate(torch.rand(3, 64, 64))
        >>> sorted(cal.to_dict())[:4]
        ['K', 'R', 'confidence', 'focal']
    """
    cfg = replace(config or ParserConfig(), seed=seed)
    if exif:
        cfg = replace(cfg, exif=True)
    if focal is not None or fov_v is not None:
        cfg = replace(cfg, focal=focal, fov_v=fov_v)
    segments = mask = None
    if isinstance(image, Tensor):
        batch, batched = as_batch(image)
    else:  # detect lines on the 8-bit image we already have instead of converting back from float
        rgb, batched = read_rgb(image), False
        batch = torch.from_numpy(rgb).permute(2, 0, 1)[None].float().div(255.0)
        segments, mask = segments_of_rgb(rgb, cfg)
        if cfg.exif and cfg.focal is None and cfg.fov_v is None and isinstance(image, (str, Path)):
            cfg = replace(cfg, focal=exif_focal(image, *rgb.shape[:2]))
    parser = _parser(weights, cfg, copy=False).to(batch.device)  # the cached networks, read only
    with torch.no_grad():
        result = parser(batch, segments, mask)
    return result if batched else result[0]
