"""The size limits of an image file, checked before anything is read or decoded: its pixel count (from the header)
and its size in bytes (against what an image of that many pixels can take).

Example:
    >>> check_pixels(100, 200, 20_000, "a.png")
    >>> check_pixels(100, 200, 19_999, "a.png")
    Traceback (most recent call last):
    ...
    ngp_kornia.errors.ImageReadError: a.png: 200x100 is 0 megapixels, over the limit of 0; ...
"""

from __future__ import annotations

import os
from pathlib import Path

from PIL import Image as PILImage

from ngp_kornia.errors import ImageReadError

__all__ = [
    "BYTES_PER_PIXEL",
    "MAX_PIXELS",
    "MAX_PIXELS_ENV",
    "METADATA_BYTES",
    "check_file_size",
    "check_pixels",
    "largest_file",
    "max_pixels",
]

#: default pixel limit of an image file (width * height): 2**27, about 134 megapixels (e.g. 13400 x 10000)
MAX_PIXELS = 2**27
#: the environment variable that overrides :data:`MAX_PIXELS`
MAX_PIXELS_ENV = "NGP_MAX_PIXELS"
#: the most bytes a pixel takes in a file of the formats read: four 16-bit channels stored uncompressed
BYTES_PER_PIXEL = 8
#: room beside the pixels for what else a file may carry: EXIF, ICC and XMP blocks, thumbnails, and data after the
#: image such as the video of a phone's motion photo (a few megabytes)
METADATA_BYTES = 64 << 20


def max_pixels() -> int:
    """The pixel limit in force: ``NGP_MAX_PIXELS`` from the environment if set, else :data:`MAX_PIXELS`.

    Raises:
        ImageReadError: ``NGP_MAX_PIXELS`` is not a positive integer.
    """
    text = os.environ.get(MAX_PIXELS_ENV)
    if text is None:
        return MAX_PIXELS
    try:
        value = int(text.replace("_", ""))
    except ValueError:
        value = 0
    if value < 1:
        raise ImageReadError(f"{MAX_PIXELS_ENV}={text!r} is not a positive whole number of pixels; e.g. 200000000")
    return value


def largest_file(pixels: int) -> int:
    """The most bytes an image file of ``pixels`` pixels can take (:data:`BYTES_PER_PIXEL` each, and
    :data:`METADATA_BYTES`)."""
    return pixels * BYTES_PER_PIXEL + METADATA_BYTES


def check_pixels(height: int, width: int, limit: int, path: str | Path) -> None:
    """Refuse an image of more than ``limit`` pixels, and one over Pillow's own decompression-bomb limit.

    Pillow's limit (twice ``PIL.Image.MAX_IMAGE_PIXELS``, 179 megapixels) still holds when ``limit`` is raised above
    it, as Pillow's WebP, TIFF and GIF readers check it themselves: raise ``PIL.Image.MAX_IMAGE_PIXELS`` as well (or
    set it to None) to read larger trusted files.

    Raises:
        ImageReadError: the image has too many pixels.
    """
    pixels = height * width
    if pixels > limit:
        raise ImageReadError(
            f"{path}: {width}x{height} is {pixels / 1e6:.0f} megapixels, over the limit of {limit / 1e6:.0f}; "
            f"downscale the image, or raise the limit with {MAX_PIXELS_ENV} (or max_pixels=) if it is trusted"
        )
    pillow = PILImage.MAX_IMAGE_PIXELS
    if pillow is not None and pixels > 2 * pillow:
        raise ImageReadError(
            f"{path}: {width}x{height} is {pixels / 1e6:.0f} megapixels, over Pillow's decompression-bomb limit of "
            f"{2 * pillow / 1e6:.0f} (twice PIL.Image.MAX_IMAGE_PIXELS); raise that too if the file is trusted"
        )


def check_file_size(size: int, pixels: int | None, limit: int, path: str | Path) -> None:
    """Refuse a file of more bytes than an image of its pixels (or, before its header is read, of ``limit`` pixels)
    can take: the rest is not image data, and reading it could exhaust memory.

    Args:
        size: the file's size in bytes.
        pixels: the pixel count its header declares; None before the header is read.
        limit: the pixel limit in force.
        path: the file, for the message.

    Raises:
        ImageReadError: the file is too large.
    """
    if pixels is None and size > largest_file(limit):
        raise ImageReadError(
            f"{path}: the file is {size / 1e9:.1f} GB, more than an image of at most {limit / 1e6:.0f} megapixels "
            f"takes ({largest_file(limit) / 1e9:.1f} GB); it is not an image file this can read"
        )
    if pixels is not None and size > largest_file(pixels):
        raise ImageReadError(
            f"{path}: the file is {size / 1e6:.0f} MB, but its header declares an image of {pixels} pixels, which "
            f"takes at most {largest_file(pixels) / 1e6:.0f} MB; the rest is not image data: re-export the image"
        )
