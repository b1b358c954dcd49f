"""Reading and checking input images: files, numpy arrays and tensors become (B, 3, H, W) float RGB in [0, 1].

Every problem raises :class:`~ngp_kornia.errors.ImageReadError` (an :class:`~ngp_kornia.errors.NGPError` and a
``ValueError``) with a message that names the input, what is wrong and what to do about it.

Files are read safely, through Pillow (and libjpeg-turbo for JPEG pixels):

- **What the path is.** Directories, named pipes, devices and looping symbolic links are refused with a line that
  says so, without being read.
- **Size limits.** The width and height are read from the file's header before anything is decoded, and a file of
  more than :func:`max_pixels` pixels (default :data:`MAX_PIXELS`, 134 megapixels; the environment variable
  ``NGP_MAX_PIXELS`` or the ``max_pixels`` argument changes it) is refused, so a small file declaring a huge image
  cannot exhaust memory; so is a file of more bytes than an image of its pixels can take. Decoding and calibration
  need about 20 bytes per pixel.
- **EXIF orientation.** Images are returned as displayed: the orientation tag (JPEG, PNG, WebP, TIFF; EXIF or XMP)
  is applied exactly once, so a phone photo stored sideways is calibrated the right way up; :func:`read_image`
  reports the tag.
- **Damaged files.** Truncated files and JPEGs whose compressed data is corrupt (which most decoders only warn about,
  filling in grey) are refused; bytes after a JPEG's end-of-image marker, common in camera files, are ignored.
  The decoders report to Python, never to the terminal, and the process's stderr is never touched (Pillow's
  warnings about a damaged EXIF block go through Python's ``warnings``, as every library's do).

JPEG pixels are decoded by libjpeg-turbo through kornia-rs, which fails on the warnings that mean damaged data; the
other formats (and CMYK JPEGs) by Pillow.
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO, NamedTuple

import cv2
import kornia_rs
import numpy as np
import torch
from PIL import Image as PILImage
from torch import Tensor

from ngp_kornia.errors import ImageReadError
from ngp_kornia.io.exif import orientation_tag
from ngp_kornia.io.files import open_file, open_image
from ngp_kornia.io.limits import MAX_PIXELS, MAX_PIXELS_ENV, check_file_size, check_pixels, max_pixels

__all__ = [
    "BACKGROUND",
    "MAX_PIXELS",
    "MAX_PIXELS_ENV",
    "MIN_SIZE",
    "ImageError",
    "ImageFile",
    "ImageReadError",
    "apply_orientation",
    "as_batch",
    "load_image",
    "max_pixels",
    "read_image",
    "read_image_file",
    "read_rgb",
    "read_rgb_oriented",
    "to_rgb_uint8",
]

MIN_SIZE = 32
#: the former name of :class:`~ngp_kornia.errors.ImageReadError`, kept so that existing ``except`` clauses work.
ImageError = ImageReadError
_SUPPORTED = "supported: JPEG, PNG, TIFF, BMP, WebP, ..."
# Pillow modes whose values are kept as they are (then converted by to_rgb_uint8); those with transparency are
# converted to RGBA (their alpha composited by to_rgb_uint8), the others to RGB
_KEPT_MODES = {"RGB", "RGBA", "L", "I;16", "I;16L", "I;16B", "I;16N", "F", "I"}
_ALPHA_MODES = {"LA", "La", "PA", "RGBa"}
#: the grey that transparent pixels are composited over: a plain background, where no line can be found
BACKGROUND = 128
_TRUNCATED = "image data is truncated (the file ends before the image does); re-export it"


class ImageFile(NamedTuple):
    """A decoded image file: ``rgb`` (H, W, 3) uint8 as displayed, and the EXIF orientation tag that was applied
    to get it (1 when the file has none: stored as displayed)."""

    rgb: np.ndarray
    orientation: int


def read_image(path: str | Path, max_pixels: int | None = None) -> ImageFile:
    """Decode an image file safely to an HxWx3 uint8 RGB array as displayed, with its EXIF orientation.

    Greyscale, 16-bit, float greyscale (in [0, 1]), palette and RGBA files are converted; the EXIF orientation is
    applied. Transparency (an alpha channel, or a palette's transparent colour) is composited over a plain grey
    (:data:`BACKGROUND`), so that pixels hidden under alpha 0 never count (their lines would).

    Args:
        path: the image file.
        max_pixels: refuse files of more pixels than this (width * height, read from the header before decoding);
            None uses :func:`max_pixels` (``NGP_MAX_PIXELS`` or :data:`MAX_PIXELS`).

    Raises:
        ImageReadError: missing, empty, too large, undecodable, truncated or corrupt files, and paths that are not
            regular files.
    """
    limit = globals()["max_pixels"]() if max_pixels is None else int(max_pixels)
    file, size = open_file(path, ImageReadError, "image file")  # before Path(): it names "" and "a://b" as given
    path = Path(path)
    with file:
        if size == 0:
            raise ImageReadError(f"{path}: file is empty")
        check_file_size(size, None, limit, path)
        image = _open(file, path)
        check_pixels(image.height, image.width, limit, path)
        check_file_size(size, image.height * image.width, limit, path)
        pixels, orientation, pending = _decode(image, file, path)
    rgb = _rgb_uint8(pixels, bgr=False, source=path)
    return ImageFile(apply_orientation(rgb, pending), orientation)


def _open(file: BinaryIO, path: Path) -> PILImage.Image:
    try:
        image = open_image(file, str(path))
    except PILImage.DecompressionBombError as err:
        raise ImageReadError(f"{path}: {err}; raise PIL.Image.MAX_IMAGE_PIXELS if the file is trusted") from None
    except (OSError, ValueError, EOFError) as err:
        if "truncated" in str(err).lower():
            raise ImageReadError(f"{path}: {_TRUNCATED}") from None
        raise ImageReadError(f"{path}: not a readable image ({err}) ({_SUPPORTED})") from None
    if image is None:
        raise ImageReadError(f"{path}: not a readable image ({_SUPPORTED})")
    return image


def _decode(image: PILImage.Image, file: BinaryIO, path: Path) -> tuple[np.ndarray, int, int]:
    """The pixels as stored, the file's orientation tag, and the orientation still to apply to the pixels.

    Pillow's TIFF reader turns the pixels by the tag itself and drops it (Pillow 11 and later): the tag read after
    decoding is what is left to apply, so that it is applied once whatever the container and the Pillow version.
    """
    if image.format == "JPEG" and image.mode in ("L", "RGB"):
        orientation = orientation_tag(image)  # read from the APP1 segments: nothing is decoded
        file.seek(0)
        try:
            pixels = kornia_rs.io.decode_image_jpegturbo(file.read(), "rgb")
        except Exception:  # kornia-rs raises a plain Exception, of one message, for every failure of libjpeg-turbo
            raise ImageReadError(
                f"{path}: the JPEG is truncated or its compressed data is corrupt (libjpeg-turbo refuses it); "
                f"re-export it"
            ) from None
        return pixels, orientation, orientation
    try:
        if image.format == "PNG":  # decoding skips the checksums of the pixel data: a damaged file would pass
            image.verify()
            image = _open(file, path)
        # the tag before decoding where that needs no decoding (a PNG's eXIf chunk may follow the pixels)
        before = orientation_tag(image) if image.format != "PNG" else None
        image.load()
        pending = orientation_tag(image)
        pixels = np.array(image if image.mode in _KEPT_MODES else image.convert(_mode_for(image)))  # a copy
    except PILImage.DecompressionBombError as err:
        raise ImageReadError(f"{path}: {err}; raise PIL.Image.MAX_IMAGE_PIXELS if the file is trusted") from None
    except (OSError, ValueError, SyntaxError, EOFError) as err:
        if "truncated" in str(err).lower():
            raise ImageReadError(f"{path}: {_TRUNCATED}") from None
        raise ImageReadError(f"{path}: the image data is damaged ({err}); re-export it") from None
    if pixels.dtype.kind == "u" and pixels.dtype.itemsize == 2:  # I;16B: big-endian 16-bit
        pixels = pixels.astype(np.uint16)
    return pixels, pending if before is None else before, pending


def read_pillow(image: PILImage.Image) -> ImageFile:
    """A Pillow image (``PIL.Image.open(path)``, say) as an HxWx3 uint8 RGB array as displayed, with its EXIF
    orientation tag, which is applied as for a file (:func:`read_image`); modes convert as a file's do.

    Raises:
        ImageReadError: an image whose pixels cannot be read (a closed file, say), or float pixels outside [0, 1].

    Example:
        >>> read_pillow(PILImage.new("LA", (5, 4))).rgb.shape
        (4, 5, 3)
    """
    orientation = orientation_tag(image)
    try:
        pixels = np.array(image if image.mode in _KEPT_MODES else image.convert(_mode_for(image)))
    except (OSError, ValueError) as err:
        raise ImageReadError(f"Pillow image: its pixels cannot be read ({err}); load it again (Image.open)") from None
    if pixels.dtype.kind in "ui" and pixels.dtype.itemsize > 1:  # 16-bit modes, and I (32-bit) of 16-bit values
        if pixels.min() < 0 or pixels.max() > 65535:
            raise ImageReadError(f"Pillow image of mode {image.mode}: values beyond 16 bits; convert it to RGB")
        pixels = pixels.astype(np.uint16)
    rgb = _rgb_uint8(pixels, bgr=False, source=None)
    return ImageFile(apply_orientation(rgb, orientation), orientation)


def _mode_for(image: PILImage.Image) -> str:
    """The mode a Pillow image not kept as it is is converted to: RGBA where it has transparency, else RGB."""
    return "RGBA" if image.mode in _ALPHA_MODES or "transparency" in image.info else "RGB"


def read_image_file(path: str | Path, max_pixels: int | None = None) -> np.ndarray:
    """Decode an image file to an HxWx3 uint8 RGB array as displayed (see :func:`read_image`).

    Raises:
        ImageReadError: missing, empty, too large, undecodable, truncated or corrupt files.
    """
    return read_image(path, max_pixels).rgb


def apply_orientation(image: np.ndarray, orientation: int) -> np.ndarray:
    """Turn an (H, W, ...) array stored with an EXIF orientation tag into the image as displayed.

    Orientation 1 is as stored, 2 mirrored left-right, 3 turned 180 degrees, 4 mirrored top-bottom, 5 transposed,
    6 stored turned 90 degrees anticlockwise (displayed turned clockwise), 7 transversed, 8 the opposite of 6.

    Example:
        >>> apply_orientation(np.array([[1, 2], [3, 4]]), 6).tolist()
        [[3, 1], [4, 2]]
    """
    if orientation == 2:
        image = image[:, ::-1]
    elif orientation == 3:
        image = image[::-1, ::-1]
    elif orientation == 4:
        image = image[::-1]
    elif orientation == 5:
        image = image.swapaxes(0, 1)
    elif orientation == 6:
        image = np.rot90(image, -1)
    elif orientation == 7:
        image = image[::-1, ::-1].swapaxes(0, 1)
    elif orientation == 8:
        image = np.rot90(image, 1)
    return np.ascontiguousarray(image)


def _float_advice(lo: float, hi: float, whole: bool, source: Path | None) -> str:
    """What to do with float pixels outside [0, 1], for the values they have and where they come from."""
    found = f"float images must lie in [0, 1], these values lie in [{lo:g}, {hi:g}]"
    depth = next((bits for bits, top in ((8, 255), (16, 65535)) if whole and lo >= 0 and hi <= top), None)
    if source is not None:
        kind = f"{depth}-bit values stored as floats" if depth else "values outside [0, 1]"
        return f"{source}: {found}: {kind}; save the image as an 8-bit or 16-bit file (or as floats in [0, 1])"
    if depth:
        return f"{found}: {depth}-bit values; divide them by {2**depth - 1}"
    return f"{found}; scale (or clip) them into [0, 1]"


def to_rgb_uint8(image: np.ndarray, bgr: bool = False) -> np.ndarray:
    """Convert an HxW, HxWx1, HxWx3 or HxWx4 array (uint8, uint16 or float in [0, 1]) to HxWx3 uint8 RGB; the
    fourth channel is alpha, composited over a plain grey (:data:`BACKGROUND`) so that hidden pixels never count.

    Example:
        >>> to_rgb_uint8(np.full((2, 2), 65535, np.uint16))[0, 0].tolist()
        [255, 255, 255]
    """
    return _rgb_uint8(image, bgr, None)


def _rgb_uint8(image: np.ndarray, bgr: bool, source: Path | None) -> np.ndarray:
    where = f"{source}: " if source is not None else ""
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in (1, 3, 4):
        raise ImageReadError(f"{where}expected an HxW, HxWx3 or HxWx4 image, got an array of shape {image.shape}")
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) / 257.0).round().astype(np.uint8)
    elif image.dtype in (np.float32, np.float64):
        if not np.isfinite(image).all():
            raise ImageReadError(f"{where}image contains NaN or infinite values")
        lo, hi = float(image.min()), float(image.max())
        if lo < 0.0 or hi > 1.0:
            raise ImageReadError(_float_advice(lo, hi, bool(np.array_equal(image, np.round(image))), source))
        image = (image * 255.0).round().astype(np.uint8)
    elif image.dtype != np.uint8:
        fix = "save it as an 8-bit or 16-bit image" if source is not None else "use uint8, uint16 or float in [0, 1]"
        raise ImageReadError(f"{where}unsupported pixel type {image.dtype}; {fix}")
    channels = image.shape[2]
    if channels == 1:
        return np.repeat(image, 3, axis=2)
    if channels == 4:
        image = _composited(image)
    if bgr:  # OpenCV's swap is many times faster than numpy's reversed copy
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(image)


def _composited(image: np.ndarray) -> np.ndarray:
    """An (H, W, 4) uint8 image with alpha as (H, W, 3), composited over :data:`BACKGROUND` (rounded)."""
    alpha = image[..., 3:]
    if bool((alpha == 255).all()):  # opaque: the colours as they are
        return np.ascontiguousarray(image[..., :3])
    mixed = image[..., :3].astype(np.uint32) * alpha + np.uint32(BACKGROUND) * (255 - alpha.astype(np.uint32))
    return ((mixed + 127) // 255).astype(np.uint8)


def _check_size(height: int, width: int, name: str) -> None:
    if min(height, width) < MIN_SIZE:
        raise ImageReadError(
            f"{name} is {width}x{height} pixels; at least {MIN_SIZE} px on each side is needed to find lines"
        )


def load_image(image: str | Path | np.ndarray | PILImage.Image) -> Tensor:
    """A file path, an HxWx3 uint8 RGB array or a Pillow image as a (1, 3, H, W) float tensor in [0, 1].

    Example:
        >>> load_image(np.zeros((40, 50, 3), np.uint8)).shape
        torch.Size([1, 3, 40, 50])
    """
    return torch.from_numpy(read_rgb(image)).permute(2, 0, 1)[None].float().div(255.0)


def read_rgb(image: str | Path | np.ndarray | PILImage.Image) -> np.ndarray:
    """A file path, an image array or a Pillow image as a checked HxWx3 uint8 RGB array (see :func:`to_rgb_uint8`);
    files and Pillow images as displayed (EXIF orientation applied).

    Example:
        >>> read_rgb(np.zeros((40, 50), np.uint16)).shape
        (40, 50, 3)
    """
    return read_rgb_oriented(image)[0]


def read_rgb_oriented(image: str | Path | np.ndarray | PILImage.Image) -> tuple[np.ndarray, int | None]:
    """:func:`read_rgb` and the EXIF orientation applied to a file or a Pillow image (None for an array, taken as
    it is).

    Example:
        >>> read_rgb_oriented(np.zeros((40, 50, 3), np.uint8))[1] is None
        True
    """
    if isinstance(image, (str, Path)):
        (rgb, orientation), name = read_image(image), str(image)
    elif isinstance(image, np.ndarray):
        rgb, orientation, name = to_rgb_uint8(image), None, "image array"
    elif isinstance(image, PILImage.Image):
        (rgb, orientation), name = read_pillow(image), "Pillow image"
    else:
        raise TypeError(
            f"expected a path, a numpy array, a Pillow image or a torch tensor, got {type(image).__name__}"
        )
    _check_size(rgb.shape[0], rgb.shape[1], name)
    return rgb, orientation


def as_batch(image: str | Path | np.ndarray | PILImage.Image | Tensor) -> tuple[Tensor, bool]:
    """Any supported input as a checked (B, 3, H, W) float tensor in [0, 1], and whether the input was batched;
    a uint8 tensor in [0, 255] is divided by 255 into float32 (on its device).

    Example:
        >>> x, batched = as_batch(torch.rand(3, 40, 40))
        >>> x.shape, batched
        (torch.Size([1, 3, 40, 40]), False)
        >>> as_batch(torch.full((2, 3, 40, 40), 255, dtype=torch.uint8))[0].amax().item()
        1.0
    """
    if not isinstance(image, Tensor):
        return load_image(image), False
    if image.dtype == torch.uint8 and not image.is_meta:
        image = image.float() / 255.0
    if not image.is_floating_point():
        raise TypeError(f"expected a float tensor in [0, 1] or a uint8 tensor in [0, 255], got {image.dtype}")
    if image.dim() not in (3, 4) or image.shape[-3] != 3:
        raise ImageReadError(f"expected a (3, H, W) or (B, 3, H, W) RGB tensor, got shape {tuple(image.shape)}")
    if image.is_meta:
        raise ImageReadError(
            f"image tensor of shape {tuple(image.shape)} is on the meta device: it has a shape but no pixel values; "
            f"give a tensor on the CPU or a GPU"
        )
    if image.numel() == 0:
        raise ImageReadError(f"empty image tensor of shape {tuple(image.shape)}: expected at least one 3xHxW image")
    if not bool(torch.isfinite(image).all()):
        raise ImageReadError("image tensor contains NaN or infinite values")
    lo, hi = float(image.min()), float(image.max())
    if lo < 0.0 or hi > 1.0:
        whole = bool(torch.equal(image, image.round()))
        raise ImageReadError("image tensor: " + _float_advice(lo, hi, whole, None).replace("float images", "values"))
    batched = image.dim() == 4
    batch = image if batched else image[None]
    _check_size(batch.shape[-2], batch.shape[-1], "image tensor")
    return batch, batched
