"""The EXIF focal length: both byte orders, the 35 mm equivalent and the sensor-resolution route, silent fall-back."""

import math
import struct
import zlib

import cv2
import numpy as np
import pytest

from ngp_kornia.io import FILM_DIAGONAL_MM, exif_focal, exif_tags, focal_from_exif_tags
from tests.image_files import LONG, RATIONAL, SHORT, tiff_block


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


def test_exif_after_200_kb_of_other_app_segments_is_found(tmp_path):
    """Cameras and editors put large APP2 (ICC profile, MPF) and APP13 blocks before or after EXIF: it is found
    wherever it sits among the header segments."""
    path = tmp_path / "big-header.jpg"
    jpeg_with_exif(path, tiff_block("MM", [(0xA405, SHORT, 28)]))
    data = path.read_bytes()
    filler = b"\xff\xe2" + struct.pack(">H", 50_002) + bytes(50_000)  # one APP2 segment of 50 kB
    path.write_bytes(data[:2] + filler * 4 + data[2:])  # the APP1 segment with EXIF now starts after 200 kB
    assert exif_focal(path, 96, 128) == pytest.approx(28 * math.hypot(96, 128) / FILM_DIAGONAL_MM)


def _png_with_exif_after_the_pixels(path, exif: bytes) -> None:
    png = cv2.imencode(".png", np.full((96, 128, 3), 90, np.uint8))[1].tobytes()
    chunk = struct.pack(">I", len(exif)) + b"eXIf" + exif + struct.pack(">I", zlib.crc32(b"eXIf" + exif))
    path.write_bytes(png[:-12] + chunk + png[-12:])  # just before IEND


def test_the_focal_length_of_a_tiff_and_of_a_png_with_exif_after_the_pixels(tmp_path):
    from PIL import Image

    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 28
    Image.fromarray(np.full((96, 128, 3), 90, np.uint8)).save(tmp_path / "a.tif", exif=exif.tobytes())
    _png_with_exif_after_the_pixels(tmp_path / "a.png", exif.tobytes())
    expected = 28 * math.hypot(96, 128) / FILM_DIAGONAL_MM
    assert exif_focal(tmp_path / "a.tif", 96, 128) == pytest.approx(expected)
    assert exif_focal(tmp_path / "a.png", 96, 128) == pytest.approx(expected)


def test_a_file_over_the_pixel_limit_is_not_decoded_for_its_exif(tmp_path, monkeypatch):
    """A PNG's EXIF after the pixels takes decoding to reach: not for a file over the limit (a bomb)."""
    from PIL import Image

    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 28
    _png_with_exif_after_the_pixels(tmp_path / "a.png", exif.tobytes())
    assert exif_focal(tmp_path / "a.png", 96, 128) is not None
    monkeypatch.setenv("NGP_MAX_PIXELS", str(96 * 128 - 1))
    assert exif_focal(tmp_path / "a.png", 96, 128) is None
