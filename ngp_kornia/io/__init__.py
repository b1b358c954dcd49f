"""Image files and EXIF, read safely through Pillow: files, numpy arrays and tensors become checked RGB images.

:mod:`ngp_kornia.io.images` reads and checks images, :mod:`ngp_kornia.io.exif` reads the orientation and focal
length a file records, :mod:`ngp_kornia.io.limits` holds the size limits and :mod:`ngp_kornia.io.files` opens a
user's files with one clear error for anything that is not a readable regular file.

>>> from ngp_kornia.io import MAX_PIXELS, read_rgb
>>> MAX_PIXELS == 2**27
True
"""

from ngp_kornia.io.exif import FILM_DIAGONAL_MM, exif_focal, exif_orientation, exif_tags, focal_from_exif_tags
from ngp_kornia.io.files import header_size, open_file
from ngp_kornia.io.images import (
    MIN_SIZE,
    ImageError,
    ImageFile,
    ImageReadError,
    apply_orientation,
    as_batch,
    load_image,
    read_image,
    read_image_file,
    read_pillow,
    read_rgb,
    read_rgb_oriented,
    to_rgb_uint8,
)
from ngp_kornia.io.limits import MAX_PIXELS, MAX_PIXELS_ENV, max_pixels

__all__ = [
    "FILM_DIAGONAL_MM",
    "MAX_PIXELS",
    "MAX_PIXELS_ENV",
    "MIN_SIZE",
    "ImageError",
    "ImageFile",
    "ImageReadError",
    "apply_orientation",
    "as_batch",
    "exif_focal",
    "exif_orientation",
    "exif_tags",
    "focal_from_exif_tags",
    "header_size",
    "load_image",
    "max_pixels",
    "open_file",
    "read_image",
    "read_image_file",
    "read_pillow",
    "read_rgb",
    "read_rgb_oriented",
    "to_rgb_uint8",
]
