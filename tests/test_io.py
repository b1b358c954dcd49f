"""Reading files safely: the pixel limit from the header, EXIF orientation, damaged JPEGs, decoder noise."""

import zlib

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia import ImageReadError, NGPError, calibrate
from ngp_kornia.io import (
    MAX_PIXELS,
    apply_orientation,
    exif_orientation,
    header_size,
    max_pixels,
    read_image,
    read_image_file,
)
from ngp_kornia.training.synth.render import render_scene
from tests.image_files import jpeg_with_orientation, png_chunk, png_declaring, png_with_orientation

# ------------------------------------------------------------------------------------------------ pixel limit


def test_pixel_limit_refuses_a_declared_giant_before_decoding(tmp_path):
    bomb = tmp_path / "bomb.png"
    # a real IDAT of a few kilobytes that would inflate to 2.7 GB: refused from the header, nothing decoded
    rows = zlib.compressobj(9)
    idat = rows.compress(bytes(1 + 30000 * 3) * 64) + rows.flush()
    bomb.write_bytes(png_declaring(30000, 30000, png_chunk(b"IDAT", idat)))
    with pytest.raises(ImageReadError, match="30000x30000 is 900 megapixels, over the limit of 134"):
        calibrate(bomb)


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tif", ".webp"])
def test_header_size_of_every_parsed_format(ext):
    ok, data = cv2.imencode(ext, np.zeros((37, 53, 3), np.uint8))
    assert header_size(data.tobytes()) == (37, 53)


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


# -------------------------------------------------------------------------------------------- EXIF orientation


def test_apply_orientation_matches_pillow_for_all_eight_tags():
    Image = pytest.importorskip("PIL.Image")
    ImageOps = pytest.importorskip("PIL.ImageOps")
    import io

    stored = (np.random.default_rng(0).random((40, 64, 3)) * 255).astype(np.uint8)
    for tag in range(1, 9):
        data = png_with_orientation(stored, tag)
        assert exif_orientation(data) == tag
        shown = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(data))).convert("RGB"))
        assert np.array_equal(apply_orientation(stored, tag), shown), tag


@pytest.fixture(scope="module")
def scene():
    return render_scene(3)


def test_phone_photo_stored_sideways_is_calibrated_as_displayed(tmp_path, scene):
    upright = scene.image
    stored = np.ascontiguousarray(np.rot90(upright, 1))  # what a phone held upright writes with orientation 6
    (tmp_path / "upright.png").write_bytes(png_with_orientation(upright, 1))
    (tmp_path / "phone.png").write_bytes(png_with_orientation(stored, 6))
    (tmp_path / "phone.jpg").write_bytes(jpeg_with_orientation(stored, 6))
    reference = calibrate(tmp_path / "upright.png")
    lossless = calibrate(tmp_path / "phone.png")
    assert int(lossless.exif_orientation) == 6 and int(reference.exif_orientation) == 1
    assert torch.equal(lossless.K, reference.K) and torch.equal(lossless.horizon, reference.horizon)
    phone = calibrate(tmp_path / "phone.jpg")
    d = phone.to_dict()
    assert d["exif_orientation"] == 6 and (d["height"], d["width"]) == upright.shape[:2]
    truth = scene.to_dict()
    assert abs(d["pitch"] - truth["pitch"]) < 1.5 and abs(d["fov_v"] - truth["fov_v"]) < 3.0
    assert calibrate(upright).to_dict()["exif_orientation"] == 1  # arrays are taken as they are


# ----------------------------------------------------------------------------------------------- damaged files


@pytest.fixture
def jpeg(tmp_path):
    rgb = (np.random.default_rng(1).random((96, 128, 3)) * 255).astype(np.uint8)
    return cv2.imencode(".jpg", rgb)[1].tobytes()


def test_truncated_jpeg_with_a_faked_end_marker_is_refused(tmp_path, jpeg):
    path = tmp_path / "cut.jpg"
    path.write_bytes(jpeg[: len(jpeg) // 2] + b"\xff\xd9")
    with pytest.raises(ImageReadError, match="cut.jpg: the JPEG is truncated or its compressed data is corrupt"):
        calibrate(path)


def test_corrupt_jpeg_scan_data_is_refused(tmp_path, jpeg):
    data = bytearray(jpeg)
    data[len(data) // 2 : len(data) // 2 + 8] = b"\xff\xd3" * 4  # restart markers where none belong
    path = tmp_path / "corrupt.jpg"
    path.write_bytes(bytes(data))
    with pytest.raises(ImageReadError, match="corrupt"):
        read_image(path)


def test_jpeg_with_bytes_after_its_end_marker_is_accepted(tmp_path, jpeg):
    path = tmp_path / "trailer.jpg"
    path.write_bytes(jpeg + b"\x00" * 5000 + b"maker notes after the image")
    assert read_image_file(path).shape == (96, 128, 3)


def test_decoder_messages_do_not_reach_the_terminal(tmp_path, capfd):
    png = cv2.imencode(".png", np.zeros((64, 64, 3), np.uint8))[1].tobytes()
    bad = bytearray(png)
    bad[len(bad) // 2] ^= 0xFF  # a CRC error
    path = tmp_path / "crc.png"
    path.write_bytes(bytes(bad))
    with pytest.raises(NGPError, match="libpng error"):
        read_image(path)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("call", [1, 2])
def test_ctrl_c_during_a_decode_gives_the_stderr_back(tmp_path, jpeg, monkeypatch, call):
    """Ctrl+C is raised at the first Python call after the signal: before the decode or right after it, in the
    step that restores the process's stderr. Either way the stderr must be the terminal's again."""
    import os

    import ngp_kornia.io as io

    path = tmp_path / "photo.jpg"
    path.write_bytes(jpeg)
    calls = []
    flush = io._flush_c_stdio

    def interrupted():
        calls.append(1)
        if len(calls) == call:
            raise KeyboardInterrupt
        flush()

    before = os.fstat(2)
    monkeypatch.setattr(io, "_flush_c_stdio", interrupted)
    with pytest.raises(KeyboardInterrupt):
        read_image(path)
    after = os.fstat(2)
    assert (after.st_dev, after.st_ino) == (before.st_dev, before.st_ino)
