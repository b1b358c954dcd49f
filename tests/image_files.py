"""Image files built byte by byte for the tests: EXIF orientation tags in JPEG and PNG, PNG headers declaring any
size (decompression bombs)."""

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
