"""Opening a user's file for reading: one clear error line for anything that is not a readable regular file, and
image files opened lazily by Pillow (the header only) so that their size can be checked before anything is decoded.

Example:
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     open_file(folder, ValueError, "weights file")
    Traceback (most recent call last):
    ...
    ValueError: ...: is a directory, expected a weights file
"""

from __future__ import annotations

import errno
import io
import os
import stat
from pathlib import Path
from typing import BinaryIO

from PIL import (
    BmpImagePlugin,
    GifImagePlugin,
    JpegImagePlugin,
    PngImagePlugin,
    PpmImagePlugin,
    TiffImagePlugin,
    WebPImagePlugin,
)
from PIL import Image as PILImage

__all__ = ["PILLOW_FORMATS", "file_kind", "header_size", "open_file", "open_image", "stored_size"]

#: the image formats read, as Pillow's classes for them. They are opened directly rather than through
#: ``PIL.Image.open``, whose decompression-bomb guard warns (``DecompressionBombWarning``, printed to stderr) for
#: every file over ``PIL.Image.MAX_IMAGE_PIXELS`` (89 megapixels) and cannot be silenced without changing the
#: process's warning filters: the pixel limit is then :func:`ngp_kornia.io.max_pixels`, checked by the caller.
PILLOW_FORMATS = (
    JpegImagePlugin.JpegImageFile,
    PngImagePlugin.PngImageFile,
    TiffImagePlugin.TiffImageFile,
    WebPImagePlugin.WebPImageFile,
    BmpImagePlugin.BmpImageFile,
    GifImagePlugin.GifImageFile,
    PpmImagePlugin.PpmImageFile,
)
_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)
# O_NONBLOCK: a FIFO put in place after the check must not block the open; O_NOCTTY: a terminal is not adopted
_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)


def _article(noun: str) -> str:
    return f"an {noun}" if noun[:1] in "aeiou" else f"a {noun}"


def file_kind(mode: int) -> str:
    """What a file of ``os.stat`` mode ``mode`` is, in words: ``"a regular file"``, ``"a directory"``, ...

    Example:
        >>> file_kind(os.stat(".").st_mode)
        'a directory'
    """
    for test, kind in _KINDS:
        if test(mode):
            return kind
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def _open_error(path: Path, err: OSError, what: str) -> str:
    """The one line for an ``OSError`` of opening ``path``: what the path is, and what to do."""
    if err.errno == errno.ELOOP:
        return f"{path}: a symbolic link that loops back on itself; point it at {_article(what)}"
    if err.errno in (errno.ENOENT, errno.ENOTDIR):
        if path.is_symlink():
            return f"{path}: file not found (a symbolic link to {os.readlink(path)}, which does not exist)"
        if str(path).startswith("~"):
            return f"{path}: file not found ('~' is not expanded here; pass os.path.expanduser(path))"
        return f"{path}: file not found"
    if err.errno in (errno.EACCES, errno.EPERM):
        return f"{path}: cannot read the file: Permission denied"
    return f"{path}: cannot read the file: {err.strerror or err}"


def open_file(path: str | Path, error: type[Exception], what: str) -> tuple[BinaryIO, int]:
    """Open ``path`` for reading if it is a regular file, and its size in bytes.

    Directories, named pipes, devices and sockets are refused without being opened (reading a FIFO would wait for a
    writer; a device may never end), as are symbolic links that loop or lead nowhere, each with one line that says
    what the path is.

    Args:
        path: the file.
        error: the exception class to raise (e.g. :class:`~ngp_kornia.errors.ImageReadError`).
        what: what the file should be, for the messages (``"image file"``, ``"weights file"``).

    Returns:
        ``(file, size)``: the file opened in binary mode (the caller closes it) and its size in bytes.

    Raises:
        error: the path does not name a readable regular file.
    """
    if str(path) == "":
        raise error(f"an empty path was given where {_article(what)} was expected")
    if "://" in str(path) and not os.path.exists(path):
        raise error(f"{path}: addresses are not downloaded; give the path of a local copy of the {what}")
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):
            raise error(f"{path}: is {file_kind(mode)}, expected {_article(what)}")
        fd = os.open(path, _OPEN_FLAGS)
    except OSError as err:
        raise error(_open_error(path, err, what)) from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):  # replaced between the check and the open
        os.close(fd)
        raise error(f"{path}: is {file_kind(info.st_mode)}, expected {_article(what)}")
    return os.fdopen(fd, "rb"), info.st_size


def open_image(file: BinaryIO, name: str = "") -> PILImage.Image | None:
    """The image in ``file`` opened lazily by Pillow (its header read, nothing decoded), or None when it is none of
    :data:`PILLOW_FORMATS`.

    Raises:
        OSError, ValueError, PIL.Image.DecompressionBombError: a file of a known format whose header is damaged or
            declares an image over Pillow's own limit (which WebP, TIFF and GIF files still check).
    """
    for kind in PILLOW_FORMATS:
        file.seek(0)
        try:
            return kind(file, name)
        except SyntaxError:  # Pillow's "not this format" (and "damaged header of this format")
            continue
    return None


def stored_size(image: PILImage.Image) -> tuple[int, int]:
    """``(height, width)`` of an opened image as its file stores it, before any EXIF orientation.

    Pillow reports a TIFF's size as displayed (turned by its orientation tag, which its loader applies); the TIFF
    tags give the stored one.
    """
    if isinstance(image, TiffImagePlugin.TiffImageFile):
        tags = image.tag_v2
        if isinstance(tags.get(256), int) and isinstance(tags.get(257), int):
            return tags[257], tags[256]
    return image.size[1], image.size[0]


def header_size(data: bytes) -> tuple[int, int] | None:
    """``(height, width)`` as stored in an image file's header, without decoding it; None when the bytes are none of
    the formats read (JPEG, PNG, TIFF, WebP, BMP, GIF, PNM) or the header is damaged or incomplete.

    Example:
        >>> import io
        >>> buffer = io.BytesIO()
        >>> PILImage.new("RGB", (50, 40)).save(buffer, "PNG")
        >>> header_size(buffer.getvalue())
        (40, 50)
    """
    try:
        image = open_image(io.BytesIO(data))
    except (OSError, ValueError, EOFError, PILImage.DecompressionBombError):
        return None
    return None if image is None else stored_size(image)
