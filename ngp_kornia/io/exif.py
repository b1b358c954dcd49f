"""EXIF through Pillow: the orientation tag of an image file, and the focal length it records, in pixels (a prior
for :func:`ngp_kornia.calibrate`).

Pillow finds the EXIF block wherever the format allows it: any APP1 segment of a JPEG (however much other data comes
first), a PNG's ``eXIf`` chunk before or after the image data, a WebP's ``EXIF`` chunk, a TIFF's own tags. The focal
length is ``FocalLengthIn35mmFilm`` (0xA405), or else ``FocalLength`` (0x920A) with ``FocalPlaneXResolution``
(0xA20E), ``FocalPlaneResolutionUnit`` (0xA210) and ``PixelXDimension`` / ``PixelYDimension`` (0xA002 / 0xA003), read
from the EXIF IFD (or IFD0, where TIFF files may keep them). Anything missing or malformed gives ``None``: the caller
then estimates the focal length itself.
"""

from __future__ import annotations

import io
import math
import struct
from pathlib import Path

from PIL import ExifTags, TiffImagePlugin
from PIL import Image as PILImage

from ngp_kornia.errors import ImageReadError
from ngp_kornia.io.files import open_file, open_image
from ngp_kornia.io.limits import check_file_size, check_pixels, max_pixels

__all__ = [
    "FILM_DIAGONAL_MM",
    "exif_focal",
    "exif_orientation",
    "exif_tags",
    "focal_from_exif_tags",
    "orientation_tag",
]

#: diagonal of a 36 x 24 mm frame: the 35 mm equivalent focal length is taken as the same diagonal field of view
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
_FOCAL_TAGS = (0xA405, 0x920A, 0xA20E, 0xA210, 0xA002, 0xA003)
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
# what Pillow raises for a damaged EXIF block or damaged image data read to reach one
_EXIF_ERRORS = (OSError, ValueError, SyntaxError, struct.error, KeyError, IndexError, TypeError, EOFError)


def orientation_tag(image: PILImage.Image) -> int:
    """The EXIF orientation tag (1-8) of an image opened by Pillow, 1 when it has none or it is malformed.

    Pillow also takes the tag from XMP where the EXIF block lacks it. For a PNG whose ``eXIf`` chunk may follow the
    image data, Pillow decodes the image to reach it.

    Example:
        >>> orientation_tag(PILImage.new("RGB", (4, 4)))
        1
    """
    try:
        value = image.getexif().get(ExifTags.Base.Orientation, 1)
    except _EXIF_ERRORS:
        return 1
    return value if isinstance(value, int) and 1 <= value <= 8 else 1


def _open_bytes(data: bytes) -> PILImage.Image | None:
    try:
        return open_image(io.BytesIO(data))
    except (*_EXIF_ERRORS, PILImage.DecompressionBombError):
        return None


def exif_orientation(data: bytes) -> int:
    """The EXIF orientation tag (1-8) of an image file's bytes (JPEG, PNG, WebP, TIFF); 1 (stored as displayed) when
    it has none.

    Example:
        >>> exif_orientation(b"not an image")
        1
    """
    image = _open_bytes(data)
    return 1 if image is None else orientation_tag(image)


def _number(value: object) -> float | None:
    """A tag's value as a float (the first of several); None for text and other kinds."""
    if isinstance(value, tuple) and value:
        value = value[0]
    if isinstance(value, (int, float, TiffImagePlugin.IFDRational)):
        return float(value)  # a rational of denominator 0 is NaN
    return None


def _focal_tags(image: PILImage.Image) -> dict[int, float]:
    try:
        ifd0 = image.getexif()
        exif = ifd0.get_ifd(ExifTags.IFD.Exif)
        found = {tag: _number(exif.get(tag, ifd0.get(tag))) for tag in _FOCAL_TAGS}
    except _EXIF_ERRORS:
        return {}
    return {tag: value for tag, value in found.items() if value is not None}


def exif_tags(data: bytes) -> dict[int, float]:
    """The focal-length tags (tag id -> value) of an image file's bytes; empty when there are none or they are
    malformed.

    Example:
        >>> exif_tags(b"not a jpeg")
        {}
    """
    image = _open_bytes(data)
    return {} if image is None else _focal_tags(image)


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
    has none (or cannot be read: :func:`ngp_kornia.io.read_image` says why).

    The file's size limits are checked first, as for reading it: a PNG may need decoding to reach its EXIF.

    Example:
        >>> exif_focal("/no/such/file.jpg", 480, 640) is None
        True
    """
    try:
        file, size = open_file(path, ImageReadError, "image file")
    except ImageReadError:
        return None
    with file:
        try:
            limit = max_pixels()
            check_file_size(size, None, limit, path)
            image = open_image(file, str(path))
            if image is None:
                return None
            check_pixels(image.height, image.width, limit, path)
            check_file_size(size, image.height * image.width, limit, path)
        except (ImageReadError, *_EXIF_ERRORS, PILImage.DecompressionBombError):
            return None
        return focal_from_exif_tags(_focal_tags(image), height, width)
