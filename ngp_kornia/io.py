"""Reading and checking input images: files, numpy arrays and tensors become (B, 3, H, W) float RGB in [0, 1].

Every problem raises :class:`~ngp_kornia.errors.ImageReadError` (an :class:`~ngp_kornia.errors.NGPError` and a
``ValueError``) with a message that names the input, what is wrong and what to do about it.

Files are read safely:

- **Pixel limit.** The width and height are read from the file's header (JPEG, PNG, BMP, TIFF, WebP, GIF, PNM)
  before anything is decoded, and a file of more than :func:`max_pixels` pixels (default :data:`MAX_PIXELS`, 134
  megapixels; the environment variable ``NGP_MAX_PIXELS`` or the ``max_pixels`` argument changes it) is refused, so a
  small file declaring a huge image cannot exhaust memory. Decoding and calibration need about 20 bytes per pixel.
  Formats whose header is not parsed here fall under OpenCV's own limit, which this module sets to the same value.
- **EXIF orientation.** Images are returned as displayed: the EXIF orientation tag (JPEG, PNG, WebP, TIFF) is
  applied, so a phone photo stored sideways is calibrated the right way up; :func:`read_image` reports the tag.
- **Damaged files.** Truncated files and JPEGs whose compressed data is corrupt (which the decoder would only warn
  about) are refused; bytes after a JPEG's end-of-image marker, common in camera files, are ignored. The decoder's
  own messages (``libpng error: ...``, ``Corrupt JPEG data: ...``) never reach the terminal: they become the error.
"""

from __future__ import annotations

import ctypes
import functools
import os
import re
import struct
import tempfile
import threading
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch
from torch import Tensor

from ngp_kornia.errors import ImageReadError

__all__ = [
    "MAX_PIXELS",
    "MAX_PIXELS_ENV",
    "MIN_SIZE",
    "ImageError",
    "ImageFile",
    "ImageReadError",
    "apply_orientation",
    "as_batch",
    "exif_block",
    "exif_orientation",
    "header_size",
    "load_image",
    "max_pixels",
    "read_image",
    "read_image_file",
    "read_rgb",
    "read_rgb_oriented",
]

MIN_SIZE = 32
#: default pixel limit of an image file (width * height): 2**27, about 134 megapixels (e.g. 13400 x 10000). The
#: package sets OpenCV's own limit (``OPENCV_IO_MAX_IMAGE_PIXELS``) to this value when it is imported first.
MAX_PIXELS = 2**27
#: the environment variable that overrides :data:`MAX_PIXELS`
MAX_PIXELS_ENV = "NGP_MAX_PIXELS"
#: the former name of :class:`~ngp_kornia.errors.ImageReadError`, kept so that existing ``except`` clauses work.
ImageError = ImageReadError


class ImageFile(NamedTuple):
    """A decoded image file: ``rgb`` (H, W, 3) uint8 as displayed, and the EXIF orientation tag that was applied
    to get it (1 when the file has none: stored as displayed)."""

    rgb: np.ndarray
    orientation: int


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


# ---------------------------------------------------------------------------------------------------- headers


def header_size(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` as stored in an image file's header, without decoding it; None when the format is not
    one this function parses (JPEG, PNG, BMP, TIFF, WebP, GIF, PNM) or the header is damaged.

    Example:
        >>> ok, png = cv2.imencode(".png", np.zeros((40, 50, 3), np.uint8))
        >>> header_size(png.tobytes())
        (40, 50)
    """
    try:
        for parse in (_png_size, _jpeg_size, _bmp_size, _webp_size, _tiff_size, _gif_size, _pnm_size):
            size = parse(data)
            if size is not None:
                return size
    except (struct.error, IndexError, ValueError):
        return None
    return None


def _png_size(data: bytes) -> tuple[int, int] | None:
    if data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return height, width


def _jpeg_segments(data: bytes):
    """``(marker, payload start, payload end)`` of a JPEG's header segments, up to the start of scan."""
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            i += 2
            continue
        length = struct.unpack(">H", data[i + 2 : i + 4])[0]
        yield marker, i + 4, i + 2 + length
        if marker == 0xDA:  # start of scan: the compressed data follows
            return
        i += 2 + length


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    if data[:2] != b"\xff\xd8":
        return None
    for marker, start, _ in _jpeg_segments(data):
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            height, width = struct.unpack(">HH", data[start + 1 : start + 5])
            return height, width
    return None


def _bmp_size(data: bytes) -> tuple[int, int] | None:
    if data[:2] != b"BM" or len(data) < 26:
        return None
    if struct.unpack("<I", data[14:18])[0] == 12:  # OS/2 core header: 16-bit sizes
        width, height = struct.unpack("<HH", data[18:22])
    else:
        width, height = struct.unpack("<ii", data[18:26])
    return abs(height), abs(width)


def _webp_size(data: bytes) -> tuple[int, int] | None:
    if data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        return None
    chunk = data[12:16]
    if chunk == b"VP8X":
        width = int.from_bytes(data[24:27], "little") + 1
        height = int.from_bytes(data[27:30], "little") + 1
        return height, width
    if chunk == b"VP8L":
        bits = struct.unpack("<I", data[21:25])[0]
        return ((bits >> 14) & 0x3FFF) + 1, (bits & 0x3FFF) + 1
    if chunk == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return height & 0x3FFF, width & 0x3FFF
    return None


def _tiff_ifd0(data: bytes) -> dict[int, int] | None:
    """The integer tags of a TIFF structure's first directory (TIFF files and EXIF blocks)."""
    if data[:4] == b"II*\x00":
        order = "<"
    elif data[:4] == b"MM\x00*":
        order = ">"
    else:
        return None
    offset = struct.unpack(order + "I", data[4:8])[0]
    count = struct.unpack(order + "H", data[offset : offset + 2])[0]
    tags = {}
    for k in range(min(count, 1024)):
        entry = data[offset + 2 + 12 * k : offset + 14 + 12 * k]
        if len(entry) < 12:
            break
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if kind == 3:  # SHORT
            tags[tag] = struct.unpack(order + "H", entry[8:10])[0]
        elif kind == 4:  # LONG
            tags[tag] = struct.unpack(order + "I", entry[8:12])[0]
    return tags


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    tags = _tiff_ifd0(data)
    if tags is None or 256 not in tags or 257 not in tags:
        return None
    return tags[257], tags[256]


def _gif_size(data: bytes) -> tuple[int, int] | None:
    if data[:4] != b"GIF8":
        return None
    width, height = struct.unpack("<HH", data[6:10])
    return height, width


def _pnm_size(data: bytes) -> tuple[int, int] | None:
    if len(data) < 2 or data[:1] != b"P" or data[1:2] not in b"123456":
        return None
    tokens: list[bytes] = []
    for line in data[2:4096].splitlines():
        tokens += line.split(b"#", 1)[0].split()
        if len(tokens) >= 2:
            return int(tokens[1]), int(tokens[0])
    return None


# ------------------------------------------------------------------------------------------------ orientation


def exif_orientation(data: bytes) -> int:
    """The EXIF orientation tag (1-8) of a JPEG, PNG, WebP or TIFF file; 1 (stored as displayed) when it has none.

    Example:
        >>> exif_orientation(b"not an image")
        1
    """
    try:
        block = exif_block(data)
        tags = _tiff_ifd0(block) if block else None
    except (struct.error, IndexError, ValueError):
        return 1
    value = (tags or {}).get(0x0112, 1)
    return value if 1 <= value <= 8 else 1


def exif_block(data: bytes) -> bytes | None:
    """The TIFF-structured EXIF data of a JPEG, PNG, WebP or TIFF file's bytes, or None."""
    if data[:2] == b"\xff\xd8":
        for marker, start, end in _jpeg_segments(data):
            if marker == 0xE1 and data[start : start + 6] == b"Exif\x00\x00":
                return data[start + 6 : end]
        return None
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        i = 8
        while i + 8 <= len(data):
            length, kind = struct.unpack(">I4s", data[i : i + 8])
            if kind == b"eXIf":
                return data[i + 8 : i + 8 + length]
            if kind in (b"IDAT", b"IEND"):
                return None
            i += 12 + length
        return None
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        i = 12
        while i + 8 <= len(data):
            kind, length = struct.unpack("<4sI", data[i : i + 8])
            if kind == b"EXIF":
                block = data[i + 8 : i + 8 + length]
                return block[6:] if block.startswith(b"Exif\x00\x00") else block
            i += 8 + length + (length & 1)
        return None
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return data
    return None


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


# ---------------------------------------------------------------------------------------------------- decoding

_DECODE_LOCK = threading.Lock()
# messages of libjpeg that mean the compressed data is damaged (it decodes anyway and fills in grey)
_JPEG_DAMAGE = ("Corrupt JPEG data", "Premature end of JPEG file", "Invalid JPEG file structure")


def _flush_c_stdio() -> None:
    flush = _c_fflush()
    if flush is not None:
        flush(None)


@functools.cache
def _c_fflush():
    """The C library's ``fflush``, looked up once (loading the library builds a new ctypes class each time, about
    0.25 ms); None where there is no C library to flush (not on POSIX): nothing was buffered by it then."""
    try:
        return ctypes.CDLL(None).fflush
    except (OSError, AttributeError):
        return None


def _decode(data: np.ndarray) -> tuple[np.ndarray | None, str]:
    """``cv2.imdecode`` with the decoder's messages (written to the C stderr) captured instead of printed.

    The process's stderr is redirected for the duration of the decode (one decode at a time, under a lock), so
    another thread's stderr output during that moment is captured too; without a stderr to redirect, the decode
    runs as it is.
    """
    with _DECODE_LOCK:
        try:
            saved = os.dup(2)
        except OSError:  # no file descriptor 2 (a detached process): nothing would be printed anyway
            saved = None
        if saved is None:
            try:
                return cv2.imdecode(data, cv2.IMREAD_UNCHANGED), ""
            except cv2.error as err:
                return None, str(err)
        with tempfile.TemporaryFile() as messages:
            try:
                _flush_c_stdio()
                os.dup2(messages.fileno(), 2)
                image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
            except cv2.error as err:  # OpenCV's own checks (its pixel limit, allocation failures)
                image = None
                os.write(2, str(err).encode())
            finally:
                # Ctrl+C during the decode is raised at the next Python call, here: the stderr must come back
                # whatever is raised, or every later message of the process would go to the deleted file
                try:
                    _flush_c_stdio()
                finally:
                    os.dup2(saved, 2)
                    os.close(saved)
            messages.seek(0)
            text = messages.read().decode("utf-8", "replace")
    return image, "; ".join(_clean(line) for line in text.splitlines() if line.strip())


# OpenCV's log prefix, e.g. "[ WARN:0@3.818] global grfmt_png.cpp:855 ": a level, a thread, a timestamp and a place
_CV_LOG_PREFIX = re.compile(r"^\[\s*[A-Z]+:\d+@[\d.]+\]\s*(global\s+)?(\S+:\d+\s+)?")


def _clean(line: str) -> str:
    """A decoder message without OpenCV's log prefix: the same file gives the same words in every run."""
    return _CV_LOG_PREFIX.sub("", line.strip())


def read_image(path: str | Path, max_pixels: int | None = None) -> ImageFile:
    """Decode an image file safely to an HxWx3 uint8 RGB array as displayed, with its EXIF orientation.

    Greyscale, 16-bit and RGBA files are converted; the EXIF orientation is applied.

    Args:
        path: the image file.
        max_pixels: refuse files of more pixels than this (width * height, read from the header before decoding);
            None uses :func:`max_pixels` (``NGP_MAX_PIXELS`` or :data:`MAX_PIXELS`).

    Raises:
        ImageReadError: missing, empty, too large, undecodable, truncated or corrupt files.
    """
    path = Path(path)
    limit = globals()["max_pixels"]() if max_pixels is None else int(max_pixels)
    if not path.exists():
        raise ImageReadError(f"{path}: file not found")
    if path.is_dir():
        raise ImageReadError(f"{path}: is a directory, expected an image file")
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as err:
        raise ImageReadError(f"{path}: cannot read the file: {err.strerror or err}") from None
    if data.size == 0:
        raise ImageReadError(f"{path}: file is empty")
    raw = data.tobytes()
    size = header_size(raw)
    if size is not None:
        _check_pixels(size[0], size[1], limit, path)
    if _is_truncated(raw):
        raise ImageReadError(f"{path}: image data is truncated (the file ends before the image does); re-export it")
    image, messages = _decode(data)
    if raw[:2] == b"\xff\xd8" and any(m in messages for m in _JPEG_DAMAGE):
        raise ImageReadError(
            f"{path}: the JPEG is truncated or its compressed data is corrupt ({_short(messages)}); re-export it"
        )
    if image is None:
        if raw[:2] == b"\xff\xd8" and b"\xff\xd9" not in raw[-(1 << 16) :]:  # no end-of-image marker
            raise ImageReadError(f"{path}: image data is truncated (the file ends before the image does); re-export it")
        if "IMAGE_PIXELS" in messages or "validateInputImageSize" in messages:
            raise ImageReadError(f"{path}: image is larger than OpenCV's pixel limit (OPENCV_IO_MAX_IMAGE_PIXELS)")
        detail = f" ({_short(messages)})" if messages else ""
        raise ImageReadError(f"{path}: not a readable image{detail} (supported: JPEG, PNG, TIFF, BMP, WebP, ...)")
    _check_pixels(image.shape[0], image.shape[1], limit, path)
    orientation = exif_orientation(raw)
    try:
        rgb = to_rgb_uint8(image, bgr=True)
    except ImageReadError as err:
        raise ImageReadError(f"{path}: {err}") from None
    return ImageFile(apply_orientation(rgb, orientation), orientation)


def read_image_file(path: str | Path, max_pixels: int | None = None) -> np.ndarray:
    """Decode an image file to an HxWx3 uint8 RGB array as displayed (see :func:`read_image`).

    Raises:
        ImageReadError: missing, empty, too large, undecodable, truncated or corrupt files.
    """
    return read_image(path, max_pixels).rgb


def _short(messages: str, limit: int = 160) -> str:
    return messages if len(messages) <= limit else messages[: limit - 3] + "..."


def _check_pixels(height: int, width: int, limit: int, path: Path) -> None:
    if height * width > limit:
        raise ImageReadError(
            f"{path}: {width}x{height} is {height * width / 1e6:.0f} megapixels, over the limit of {limit / 1e6:.0f}; "
            f"downscale the image, or raise the limit with {MAX_PIXELS_ENV} (or max_pixels=) if it is trusted"
        )


def _is_truncated(data: bytes) -> bool:
    # JPEGs are checked by the decoder's own messages: a valid one may carry bytes after its end marker
    if data.startswith(b"\x89PNG"):  # PNG: must end with the IEND chunk
        return b"IEND" not in data[-64:]
    return False


def to_rgb_uint8(image: np.ndarray, bgr: bool = False) -> np.ndarray:
    """Convert an HxW, HxWx1, HxWx3 or HxWx4 array (uint8, uint16 or float in [0, 1]) to HxWx3 uint8 RGB."""
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[2] not in (1, 3, 4):
        raise ImageReadError(f"expected an HxW, HxWx3 or HxWx4 image, got an array of shape {image.shape}")
    if image.dtype == np.uint16:
        image = (image.astype(np.float32) / 257.0).round().astype(np.uint8)
    elif image.dtype in (np.float32, np.float64):
        if not np.isfinite(image).all():
            raise ImageReadError("image contains NaN or infinite values")
        if image.min() < 0.0 or image.max() > 1.0:
            raise ImageReadError("float images must lie in [0, 1]; divide 8-bit values by 255")
        image = (image * 255.0).round().astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ImageReadError(f"unsupported pixel type {image.dtype}; use uint8, uint16 or float in [0, 1]")
    channels = image.shape[2]
    if channels == 1:
        return np.repeat(image, 3, axis=2)
    if bgr and image.dtype == np.uint8:  # OpenCV's swap is many times faster than numpy's reversed copy
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if channels == 4 else cv2.COLOR_BGR2RGB)
    image = image[..., :3]  # drop alpha
    return np.ascontiguousarray(image[..., ::-1] if bgr else image)


def _check_size(height: int, width: int, name: str) -> None:
    if min(height, width) < MIN_SIZE:
        raise ImageReadError(
            f"{name} is {width}x{height} pixels; at least {MIN_SIZE} px on each side is needed to find lines"
        )


def load_image(image: str | Path | np.ndarray) -> Tensor:
    """A file path or an HxWx3 uint8 RGB array as a (1, 3, H, W) float tensor in [0, 1].

    Example:
        >>> load_image(np.zeros((40, 50, 3), np.uint8)).shape
        torch.Size([1, 3, 40, 50])
    """
    return torch.from_numpy(read_rgb(image)).permute(2, 0, 1)[None].float().div(255.0)


def read_rgb(image: str | Path | np.ndarray) -> np.ndarray:
    """A file path or an image array as a checked HxWx3 uint8 RGB array (see :func:`to_rgb_uint8`); files as
    displayed (EXIF orientation applied).

    Example:
        >>> read_rgb(np.zeros((40, 50), np.uint16)).shape
        (40, 50, 3)
    """
    return read_rgb_oriented(image)[0]


def read_rgb_oriented(image: str | Path | np.ndarray) -> tuple[np.ndarray, int | None]:
    """:func:`read_rgb` and the EXIF orientation applied to a file (None for an array, taken as it is).

    Example:
        >>> read_rgb_oriented(np.zeros((40, 50, 3), np.uint8))[1] is None
        True
    """
    if isinstance(image, (str, Path)):
        (rgb, orientation), name = read_image(image), str(image)
    elif isinstance(image, np.ndarray):
        rgb, orientation, name = to_rgb_uint8(image), None, "image array"
    else:
        raise TypeError(f"expected a path, a numpy array or a torch tensor, got {type(image).__name__}")
    _check_size(rgb.shape[0], rgb.shape[1], name)
    return rgb, orientation


def as_batch(image: str | Path | np.ndarray | Tensor) -> tuple[Tensor, bool]:
    """Any supported input as a checked (B, 3, H, W) float tensor in [0, 1], and whether the input was batched.

    Example:
        >>> x, batched = as_batch(torch.rand(3, 40, 40))
        >>> x.shape, batched
        (torch.Size([1, 3, 40, 40]), False)
    """
    if not isinstance(image, Tensor):
        return load_image(image), False
    if not image.is_floating_point():
        raise TypeError(f"expected a float tensor in [0, 1], got {image.dtype}; for uint8 use image.float() / 255")
    if image.dim() not in (3, 4) or image.shape[-3] != 3:
        raise ImageReadError(f"expected a (3, H, W) or (B, 3, H, W) RGB tensor, got shape {tuple(image.shape)}")
    if image.numel() == 0:
        raise ImageReadError(f"empty image tensor of shape {tuple(image.shape)}: expected at least one 3xHxW image")
    if not bool(torch.isfinite(image).all()):
        raise ImageReadError("image tensor contains NaN or infinite values")
    if float(image.min()) < 0.0 or float(image.max()) > 1.0:
        raise ImageReadError("image tensor values must lie in [0, 1]; divide 8-bit values by 255")
    batched = image.dim() == 4
    batch = image if batched else image[None]
    _check_size(batch.shape[-2], batch.shape[-1], "image tensor")
    return batch, batched
