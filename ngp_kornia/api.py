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
    image: str | Path | np.ndarray | Tensor | Sequence[str | Path | np.ndarray | Tensor],
    weights: str = "default",
    seed: int = 0,
    config: ParserConfig | None = None,
) -> Calibration | list[Calibration]:
    """Calibrate a camera from one photo (or a batch, or a list of photos) of a man-made scene.

    Args:
        image: a file path, an HxWx3 uint8 RGB array (HxW greyscale, RGBA and uint16 are converted), or a float
            tensor (3, H, W) or (B, 3, H, W) in [0, 1] on any device; or a list (or tuple) of any of these, of any
            sizes, mixed freely.
        weights: ``"default"`` (the best path shipped), ``"none"`` (the untrained geometric path), ``"zsnet"`` (zenith
            candidates scored by the shipped ZSNet), ``"fsnet"`` (frames rescored by the shipped FSNet), ``"full"``
            (both), or the path of a weights file (or a list of paths: one ZSNet and one FSNet file).
        seed: seed of the random candidate sampling; the same input and seed give the same result.
        config: pipeline settings (:class:`ngp_kornia.models.ParserConfig`).

    Returns:
        a :class:`Calibration` in the input's pixels: ``K``, ``R``, ``focal``, ``fov_v``, ``fov_h``, ``pitch``,
        ``roll``, ``yaw``, ``up``, ``zenith``, ``horizon``, ``vps``, ``score``, ``valid``; batched (leading dim B) for
        batched tensor input. Pixels: x right, y down, origin at the centre of the top-left pixel. Camera: x right,
        y down, z forward. Pitch > 0 looks up; roll > 0 when the scene's up leans right in the image. Degrees.
        For a list: a list of results, one per item, each exactly what that item gives alone (same seed).

    Raises:
        ImageError: unreadable, truncated, too small (< 32 px) or NaN input; the message says what to fix.
        WeightsError: a missing, corrupt or mismatched weights file.
        TypeError: an input type or dtype that is not supported.

    Example:
        >>> cal = calibrate(torch.rand(3, 64, 64))
        >>> {"K", "R", "focal", "fov_h"} <= set(cal.to_dict())
        True
        >>> [c.image_size.tolist() for c in calibrate([torch.rand(3, 64, 64), torch.rand(3, 48, 80)])]
        [[64, 64], [48, 80]]
    """
    if isinstance(image, (list, tuple)):
        return _calibrate_list(image, weights, seed, config)
    cfg = replace(config or ParserConfig(), seed=seed)
    segments = mask = None
    if isinstance(image, Tensor):
        batch, batched = as_batch(image)
    else:  # detect lines on the 8-bit image we already have instead of converting back from float
        rgb, batched = read_rgb(image), False
        batch = torch.from_numpy(rgb).permute(2, 0, 1)[None].float().div(255.0)
        segments, mask = segments_of_rgb(rgb, cfg)
    parser = _parser(weights, cfg, copy=False).to(batch.device)  # the cached networks, read only
    with torch.no_grad():
        result = parser(batch, segments, mask)
    return result if batched else result[0]


def _calibrate_list(images, weights, seed: int, config: ParserConfig | None) -> list[Calibration]:
    """One result per item, each computed alone (so it equals what the item gives alone, whatever its size)."""
    if not images:
        raise ValueError("calibrate() got an empty list; give at least one image (path, array or tensor)")
    _networks(weights)  # a bad weight set is reported once, before any image is read
    results = []
    for index, item in enumerate(images):
        if isinstance(item, (list, tuple)):
            raise TypeError(f"calibrate(): item {index} is a {type(item).__name__}; lists of lists are not supported")
        results.append(calibrate(item, weights=weights, seed=seed, config=config))
    return results
