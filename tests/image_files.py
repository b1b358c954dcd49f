"""Image files built byte by byte for the tests: EXIF orientation tags in JPEG, PNG, WebP and TIFF, EXIF blocks with
focal-length tags, PNG headers declaring any size (decompression bombs)."""

import struct
import zlib

import cv2
import numpy as np


def exif_app1(orientation: int) -> bytes:
    """A JPEG APP1 segment holding an EXIF block with one tag: the orientation."""
    tiff = b"MM\x00*" + struct.pack(">I", 8) + struct.pack(">H", 1)
    tiff += struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0)
    body = b"Exif\x00\x00" + tiff
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def jpeg_with_orientation(rgb: np.ndarray, orientation: int, quality: int = 95) -> bytes:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    data = data.tobytes()
    return data[:2] + exif_app1(orientation) + data[2:]  # right after the start-of-image marker


def png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_with_orientation(rgb: np.ndarray, orientation: int) -> bytes:
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    data = data.tobytes()
    exif = exif_app1(orientation)[10:]  # the TIFF block without the APP1 header
    return data[:33] + png_chunk(b"eXIf", exif) + data[33:]  # after the 8-byte signature and the IHDR chunk


def png_declaring(width: int, height: int, body: bytes = b"") -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + body + png_chunk(b"IEND", b"")


def png_with_orientation_after_pixels(rgb: np.ndarray, orientation: int) -> bytes:
    """A PNG whose eXIf chunk follows the image data (allowed; some writers put it there), just before IEND."""
    data = png_with_orientation(rgb, 1)
    exif = exif_app1(orientation)[10:]
    plain = data[:33] + data[33 + len(png_chunk(b"eXIf", exif)) :]  # without the eXIf chunk after IHDR
    return plain[:-12] + png_chunk(b"eXIf", exif) + plain[-12:]  # IEND is the last 12 bytes


def pillow_with_orientation(rgb: np.ndarray, orientation: int, kind: str) -> bytes:
    """A lossless WebP or an uncompressed TIFF written by Pillow, with the orientation tag: EXIF for WebP, the TIFF's
    own tag for TIFF."""
    import io

    from PIL import Image

    buffer = io.BytesIO()
    image = Image.fromarray(rgb)
    if kind == "TIFF":
        image.save(buffer, "TIFF", tiffinfo={0x0112: orientation})
    else:
        exif = Image.Exif()
        exif[0x0112] = orientation
        image.save(buffer, kind, lossless=True, exif=exif.tobytes())
    return buffer.getvalue()


SHORT, LONG, RATIONAL = 3, 4, 5


def tiff_block(order: str, entries: list[tuple[int, int, object]]) -> bytes:
    """A TIFF block whose IFD0 points to an EXIF IFD holding ``entries`` (tag, type, value)."""
    o = "<" if order == "II" else ">"
    exif_offset = 8 + 2 + 12 + 4
    data_offset = exif_offset + 2 + 12 * len(entries) + 4
    head = order.encode() + struct.pack(o + "HI", 42, 8)
    ifd0 = struct.pack(o + "H", 1) + struct.pack(o + "HHII", 0x8769, LONG, 1, exif_offset) + struct.pack(o + "I", 0)
    body, extra = struct.pack(o + "H", len(entries)), b""
    for tag, kind, value in entries:
        if kind == SHORT:
            body += struct.pack(o + "HHIHH", tag, kind, 1, value, 0)
        elif kind == LONG:
            body += struct.pack(o + "HHII", tag, kind, 1, value)
        else:  # rational stored after the IFD
            body += struct.pack(o + "HHII", tag, kind, 1, data_offset + len(extra))
            extra += struct.pack(o + "II", *value)
    return head + ifd0 + body + struct.pack(o + "I", 0) + extra
