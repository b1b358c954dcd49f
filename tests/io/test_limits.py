"""The size limits of a file, checked before it is read: the pixel count its header declares, and its size in bytes
against what an image of that many pixels can take."""

import zlib

import cv2
import numpy as np
import pytest

from ngp_kornia import ImageReadError, calibrate
from ngp_kornia.io import MAX_PIXELS, max_pixels, read_image, read_image_file
from tests.image_files import png_chunk, png_declaring


def test_pixel_limit_refuses_a_declared_giant_before_decoding(tmp_path):
    bomb = tmp_path / "bomb.png"
    # a real IDAT of a few kilobytes that would inflate to 2.7 GB: refused from the header, nothing decoded
    rows = zlib.compressobj(9)
    idat = rows.compress(bytes(1 + 30000 * 3) * 64) + rows.flush()
    bomb.write_bytes(png_declaring(30000, 30000, png_chunk(b"IDAT", idat)))
    with pytest.raises(ImageReadError, match="30000x30000 is 900 megapixels, over the limit of 134"):
        calibrate(bomb)


def test_pillow_limit_still_holds_when_ours_is_raised(tmp_path, monkeypatch):
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(png_declaring(30000, 30000))
    monkeypatch.setenv("NGP_MAX_PIXELS", str(10**10))
    with pytest.raises(ImageReadError, match="900 megapixels, over Pillow's decompression-bomb limit of 179"):
        read_image(bomb)


def test_pixel_limit_is_configurable_by_argument_and_environment(tmp_path, monkeypatch):
    path = tmp_path / "small.png"
    cv2.imwrite(str(path), np.zeros((100, 200, 3), np.uint8))
    assert max_pixels() == MAX_PIXELS == 2**27
    with pytest.raises(ImageReadError, match="200x100 is 0 megapixels, over the limit"):
        read_image_file(path, max_pixels=19_999)
    assert read_image_file(path, max_pixels=20_000).shape == (100, 200, 3)
    monkeypatch.setenv("NGP_MAX_PIXELS", "19999")
    with pytest.raises(ImageReadError, match="NGP_MAX_PIXELS"):
        calibrate(path)
    monkeypatch.setenv("NGP_MAX_PIXELS", "lots")
    with pytest.raises(ImageReadError, match="NGP_MAX_PIXELS='lots' is not a positive whole number"):
        calibrate(path)


def _sparse(path, header: bytes, size: int):
    """A file of ``size`` bytes that starts with ``header`` and takes no disk space for the rest."""
    with open(path, "wb") as file:
        file.write(header)
        file.truncate(size)
    return path


def test_a_sparse_3_gb_file_with_a_png_header_is_refused_before_reading(tmp_path):
    path = _sparse(tmp_path / "huge.png", png_declaring(64, 64), 3 << 30)
    with pytest.raises(ImageReadError, match=r"huge.png: the file is 3.2 GB, more than an image of at most 134 mega"):
        read_image(path)


def test_a_file_far_larger_than_its_declared_image_is_refused(tmp_path):
    # 100 MB behind a header of 64 x 64 pixels: more than any 64 x 64 image with its metadata takes
    path = _sparse(tmp_path / "padded.png", png_declaring(64, 64), 100 << 20)
    with pytest.raises(ImageReadError, match="padded.png: the file is 105 MB, but its header declares .* 4096 pixels"):
        read_image(path)
