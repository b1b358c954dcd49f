"""The EXIF focal length: both byte orders, the 35 mm equivalent and the sensor-resolution route, silent fall-back."""

import math
import struct

import cv2
import numpy as np
import pytest

from ngp_kornia.exif import FILM_DIAGONAL_MM, exif_focal, exif_tags, focal_from_exif_tags

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


def jpeg_with_exif(path, tiff: bytes | None, size=(96, 128)) -> None:
    img = np.full((*size, 3), 90, np.uint8)
    cv2.line(img, (10, 10), (100, 80), (255, 255, 255), 2)
    data = cv2.imencode(".jpg", img)[1].tobytes()
    if tiff is not None:
        segment = b"Exif\x00\x00" + tiff
        data = data[:2] + b"\xff\xe1" + struct.pack(">H", len(segment) + 2) + segment + data[2:]
    path.write_bytes(data)


@pytest.mark.parametrize("order", ["II", "MM"])
def test_35mm_equivalent_in_both_byte_orders(tmp_path, order):
    path = tmp_path / "a.jpg"
    jpeg_with_exif(path, tiff_block(order, [(0xA405, SHORT, 28)]))
    assert exif_tags(path.read_bytes()) == {0xA405: 28.0}
    expected = 28 * math.hypot(96, 128) / FILM_DIAGONAL_MM
    assert exif_focal(path, 96, 128) == pytest.approx(expected)
    assert cv2.imread(str(path)) is not None  # still a valid JPEG


def test_focal_length_with_focal_plane_resolution_scaled_to_the_image(tmp_path):
    # 4 mm lens, 250 px per mm on a sensor 1280 px wide; the file holds it at 640 px: f = 4 * 250 / 2 = 500 px
    entries = [(0x920A, RATIONAL, (4, 1)), (0xA20E, RATIONAL, (250, 1)), (0xA210, SHORT, 4), (0xA002, LONG, 1280)]
    path = tmp_path / "b.jpg"
    jpeg_with_exif(path, tiff_block("II", entries))
    assert exif_focal(path, 480, 640) == pytest.approx(500.0)


def test_missing_or_broken_exif_gives_none(tmp_path):
    plain = tmp_path / "plain.jpg"
    jpeg_with_exif(plain, None)
    assert exif_focal(plain, 96, 128) is None
    assert exif_focal(tmp_path / "absent.jpg", 96, 128) is None
    broken = tmp_path / "broken.jpg"
    jpeg_with_exif(broken, tiff_block("II", [(0xA405, SHORT, 28)])[:12])  # cut inside the IFD
    assert exif_focal(broken, 96, 128) is None
    assert focal_from_exif_tags({0xA405: 0.0}, 96, 128) is None  # 0 means unknown in EXIF
    assert focal_from_exif_tags({0x920A: 4.0}, 96, 128) is None  # a focal length without the sensor size
