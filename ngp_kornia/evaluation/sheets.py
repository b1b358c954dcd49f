"""Worst-case sheets: the images a method got most wrong, each drawn with its calibration (segments, vanishing
points, horizon) and the true horizon beside it, tiled into one PNG per set and weight spec.

``python -m ngp_kornia.evaluation ... --sheets DIR`` writes them for the first seed of every run; a sheet is the
quickest way to see whether the misses share a cause (clutter, a wrong zenith, a level camera facing a wall).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from ngp_kornia.evaluation.datasets import LabelledImage
from ngp_kornia.io import read_rgb
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.viz import draw_calibration

__all__ = ["TILE_WIDTH", "sheet_name", "worst_images", "worst_sheet"]

#: the width of each image on a sheet, pixels
TILE_WIDTH = 480


def worst_images(per_image: Sequence[dict], count: int, metric: str = "horizon") -> list[int]:
    """The indices of the ``count`` largest errors of ``metric`` in an evaluation's per-image rows
    (:func:`~ngp_kornia.evaluation.scoring.evaluate`), largest first; a failed image (NaN) counts as the largest.

    Example:
        >>> worst_images([{"horizon": 0.1}, {"horizon": float("nan")}, {"horizon": 0.3}], 2)
        [1, 2]
    """
    def error(i: int) -> float:
        value = per_image[i].get(metric, math.nan)
        return math.inf if value is None or math.isnan(value) else value

    return sorted(range(len(per_image)), key=error, reverse=True)[:count]


def _tile(image: LabelledImage, calibration: Calibration, caption: str) -> np.ndarray:
    rgb = read_rgb(image.image_path)
    segments = detect_segments(rgb)[0][0].numpy()
    truth = image if image.horizon is not None else None
    drawn = draw_calibration(rgb, calibration, segments, truth=truth)
    height = round(drawn.shape[0] * TILE_WIDTH / drawn.shape[1])
    tile = cv2.resize(drawn, (TILE_WIDTH, height), interpolation=cv2.INTER_AREA)
    band = np.full((22, TILE_WIDTH, 3), 20, np.uint8)
    cv2.putText(band, caption[:70], (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return np.concatenate([band, tile])


def worst_sheet(
    images: Sequence[LabelledImage],
    per_image: Sequence[dict],
    calibration: Callable[[LabelledImage], Calibration],
    path: str | Path,
    count: int = 8,
    columns: int = 4,
) -> Path:
    """Write the sheet of a method's ``count`` worst images by horizon error.

    Args:
        images: the set's images; per_image: the method's per-image rows on them (same order).
        calibration: the method's calibration of an image (:func:`~ngp_kornia.evaluation.methods.calibration_method`,
            the same answer the rows were scored on).
        path: the PNG to write (its folder is created).
        count: images on the sheet; columns: tiles per row.

    Returns:
        the path written.
    """
    tiles = []
    for i in worst_images(per_image, count):
        error = per_image[i].get("horizon", math.nan)
        caption = f"{images[i].name}: horizon error {100 * error:.1f}% of the height"
        tiles.append(_tile(images[i], calibration(images[i]), caption))
    if not tiles:
        raise ValueError("no images to draw")
    height = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, height - t.shape[0]), (0, 0), (0, 0))) for t in tiles]
    tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    rows = [np.concatenate(tiles[r : r + columns], 1) for r in range(0, len(tiles), columns)]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(rows), cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")
    return path


def sheet_name(set_name: str, spec: str) -> str:
    """A file name for the sheet of a set and a weight spec: ``<set>__<spec>.png`` with anything but letters,
    digits, ``.`` and ``-`` made ``_``.

    Example:
        >>> sheet_name("York Urban", "default:gravity_noise=1")
        'York_Urban__default_gravity_noise_1.png'
    """
    return re.sub(r"[^A-Za-z0-9.-]", "_", set_name) + "__" + re.sub(r"[^A-Za-z0-9.-]", "_", spec) + ".png"
