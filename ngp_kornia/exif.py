"""The focal length an image file's EXIF block records, in pixels: a prior for :func:`ngp_kornia.calibrate`.

A small reader of the EXIF block (found by :func:`ngp_kornia.io.exif_block` in JPEG, PNG, WebP and TIFF files; TIFF
layout, either byte order): it follows IFD0 to the EXIF IFD
and reads ``FocalLengthIn35mmFilm`` (0xA405), or else ``FocalLength`` (0x920A) with ``FocalPlaneXResolution``
(0xA20E), ``FocalPlaneResolutionUnit`` (0xA210) and ``PixelXDimension`` / ``PixelYDimension`` (0xA002 / 0xA003).
Anything missing or malformed gives ``None``: the caller then estimates the focal length itself.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

from ngp_kornia.io import exif_block

__all__ = ["exif_focal", "exif_tags", "focal_from_exif_tags"]

#: diagonal of a 36 x 24 mm frame: the 35 mm equivalent focal length is taken as the same diagonal field of view
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
_TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 9: 4, 10: 8}
_EXIF_IFD = 0x8769
_WANTED = {0xA405, 0x920A, 0xA20E, 0xA210, 0xA002, 0xA003}
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


def _read_ifd(tiff: bytes, offset: int, order: str, tags: dict[int, float]) -> int | None:
    """Read the wanted numeric tags of one IFD into ``tags``; returns the EXIF IFD's offset if listed."""
    (count,) = struct.unpack(order + "H", tiff[offset : offset + 2])
    exif_ifd = None
    for i in range(count):
        entry = tiff[offset + 2 + 12 * i : offset + 14 + 12 * i]
        if len(entry) < 12:
            break
        tag, kind, n = struct.unpack(order + "HHI", entry[:8])
        if tag == _EXIF_IFD:
            exif_ifd = struct.unpack(order + "I", entry[8:12])[0]
            continue
        if tag not in _WANTED or n < 1 or kind not in _TYPE_SIZES:
            continue
        size = _TYPE_SIZES[kind]
        raw = entry[8:12] if size <= 4 else tiff[struct.unpack(order + "I", entry[8:12])[0] :][:size]
        if kind == 3:
            value = float(struct.unpack(order + "H", raw[:2])[0])
        elif kind in (4, 9):
            value = float(struct.unpack(order + ("I" if kind == 4 else "i"), raw[:4])[0])
        elif kind in (5, 10) and len(raw) == 8:
            num, den = struct.unpack(order + ("II" if kind == 5 else "ii"), raw)
            value = num / den if den else math.nan
        elif kind in (1, 7):
            value = float(raw[0])
        else:
            continue
        tags[tag] = value
    return exif_ifd


def exif_tags(data: bytes) -> dict[int, float]:
    """The focal-length tags (tag id -> value) of a JPEG file's bytes; empty when there are none or they are
    malformed.

    Example:
        >>> exif_tags(b"not a jpeg")
        {}
    """
    tiff = exif_block(data)
    if tiff is None or len(tiff) < 8 or tiff[:2] not in (b"II", b"MM"):
        return {}
    order = "<" if tiff[:2] == b"II" else ">"
    tags: dict[int, float] = {}
    try:
        (ifd0,) = struct.unpack(order + "I", tiff[4:8])
        exif_ifd = _read_ifd(tiff, ifd0, order, tags)
        if exif_ifd is not None:
            _read_ifd(tiff, exif_ifd, order, tags)
    except (struct.error, IndexError):
        return {}
    return tags


def focal_from_exif_tags(tags: dict[int, float], height: int, width: int) -> float | None:
    """Focal length in pixels of an ``height`` x ``width`` image from its EXIF tags (see :func:`exif_tags`).

    ``FocalLengthIn35mmFilm`` keeps the diagonal field of view of a 36 x 24 mm frame:
    ``f = f35 * hypot(W, H) / hypot(36, 24)``. Otherwise ``FocalLength`` (mm) times the focal-plane resolution
    (pixels per mm of the sensor), scaled by the image's size over ``PixelXDimension`` when the file was resized.

    Example:
        >>> round(focal_from_exif_tags({0xA405: 35.0}, 2000, 3000), 1)  # a 35 mm lens on a 3:2 full frame
        2916.7
        >>> focal_from_exif_tags({}, 480, 640) is None
        True
    """
    f35 = tags.get(0xA405, 0.0)
    if math.isfinite(f35) and f35 > 0:
        return f35 * math.hypot(width, height) / FILM_DIAGONAL_MM
    f_mm, res, unit = tags.get(0x920A, math.nan), tags.get(0xA20E, math.nan), tags.get(0xA210, 2.0)
    if not (math.isfinite(f_mm) and f_mm > 0 and math.isfinite(res) and res > 0 and unit in _UNIT_MM):
        return None
    focal = f_mm * res / _UNIT_MM[unit]
    full = max(tags.get(0xA002, 0.0), tags.get(0xA003, 0.0))
    if full > 0:
        focal *= max(height, width) / full
    return focal if math.isfinite(focal) and focal > 0 else None


def exif_focal(path: str | Path, height: int, width: int) -> float | None:
    """The EXIF focal length of an image file in pixels of its ``height`` x ``width`` image, or None when the file
    has none (or is not a JPEG).

    Example:
        >>> exif_focal("/no/such/file.jpg", 480, 640) is None
        True
    """
    try:
        with open(path, "rb") as file:
            data = file.read(1 << 17)  # APP1 segments are at most 64 KiB and come first
    except OSError:
        return None
    return focal_from_exif_tags(exif_tags(data), height, width)
