"""Reading files safely: the pixel limit from the header, EXIF orientation, damaged files, decoder noise."""

import threading
import time

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia import ImageReadError, NGPError, calibrate
from ngp_kornia.io import apply_orientation, exif_orientation, read_image, read_image_file, to_rgb_uint8
from ngp_kornia.training.synth.render import render_scene
from tests.image_files import (
    jpeg_with_orientation,
    pillow_with_orientation,
    png_with_orientation,
    png_with_orientation_after_pixels,
)

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
    # a JPEG of the render, calibrated the right way up: degrees off (a turn left unapplied would be 90 off)
    assert abs(d["pitch"] - truth["pitch"]) < 3.0 and abs(d["fov_v"] - truth["fov_v"]) < 3.0
    assert calibrate(upright).to_dict()["exif_orientation"] == 1  # arrays are taken as they are


def _stored(upright: np.ndarray, tag: int) -> np.ndarray:
    """The pixels a file tagged ``tag`` stores for an image displayed as ``upright``."""
    return np.ascontiguousarray(upright[::-1, ::-1] if tag == 3 else np.rot90(upright, 1))


@pytest.mark.parametrize("tag", [3, 6])
@pytest.mark.parametrize("container", ["PNG", "PNG, eXIf after the pixels", "WEBP", "TIFF"])
def test_orientation_is_applied_exactly_once_in_every_container(tmp_path, container, tag):
    upright = (np.random.default_rng(tag).random((40, 64, 3)) * 255).astype(np.uint8)
    stored = _stored(upright, tag)
    if container == "PNG":
        data = png_with_orientation(stored, tag)
    elif container.startswith("PNG"):
        data = png_with_orientation_after_pixels(stored, tag)
    else:
        data = pillow_with_orientation(stored, tag, container)
    assert exif_orientation(data) == tag
    path = tmp_path / "image"  # no extension: the format is told by the content
    path.write_bytes(data)
    rgb, orientation = read_image(path)
    assert orientation == tag and np.array_equal(rgb, upright)  # lossless containers: the very pixels


@pytest.mark.parametrize("tag", [3, 6])
def test_orientation_of_a_jpeg_is_applied_exactly_once(tmp_path, tag):
    stored = _stored((np.random.default_rng(tag).random((40, 64, 3)) * 255).astype(np.uint8), tag)
    (tmp_path / "tagged.jpg").write_bytes(jpeg_with_orientation(stored, tag))
    (tmp_path / "plain.jpg").write_bytes(jpeg_with_orientation(stored, 1))  # the same compressed pixels
    rgb, orientation = read_image(tmp_path / "tagged.jpg")
    assert orientation == tag and np.array_equal(rgb, apply_orientation(read_image_file(tmp_path / "plain.jpg"), tag))


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


def test_damaged_png_is_refused_without_decoder_noise(tmp_path, capfd):
    png = cv2.imencode(".png", np.zeros((64, 64, 3), np.uint8))[1].tobytes()
    bad = bytearray(png)
    bad[len(bad) // 2] ^= 0xFF  # inside the compressed pixels
    path = tmp_path / "crc.png"
    path.write_bytes(bytes(bad))
    with pytest.raises(NGPError, match="crc.png: the image data is damaged"):
        read_image(path)
    assert capfd.readouterr().err == ""


# ------------------------------------------------------------------------------------------- float pixel values


def test_a_float_tiff_of_8_bit_values_is_told_to_be_saved_as_8_bit(tmp_path):
    from PIL import Image

    path = tmp_path / "depth.tif"
    Image.fromarray(np.arange(64 * 64, dtype=np.float32).reshape(64, 64) % 256).save(path)
    message = r"depth.tif: .* lie in \[0, 255\]: 8-bit values stored as floats; save"
    with pytest.raises(ImageReadError, match=message) as e:
        read_image(path)
    assert "divide" not in str(e.value)
    Image.fromarray(np.full((64, 64), 0.5, np.float32)).save(path)  # floats in [0, 1] are read
    assert np.array_equal(read_image_file(path), np.full((64, 64, 3), 128, np.uint8))


@pytest.mark.parametrize(
    "values, advice",
    [
        (np.arange(256, dtype=np.float32), r"8-bit values; divide them by 255"),
        (np.arange(0, 65536, 257, dtype=np.float32), r"16-bit values; divide them by 65535"),
        (np.linspace(0, 1.5, 256, dtype=np.float32), r"\[0, 1.5\]; scale \(or clip\) them into \[0, 1\]"),
        (np.linspace(-1, 1, 256, dtype=np.float32), r"\[-1, 1\]; scale \(or clip\) them into \[0, 1\]"),
    ],
    ids=["8-bit", "16-bit", "overshoot", "signed"],
)
def test_the_advice_for_float_values_out_of_range_fits_the_values(values, advice):
    image = np.resize(values, (64, 64))
    with pytest.raises(ImageReadError, match=advice):
        to_rgb_uint8(image)
    with pytest.raises(ImageReadError, match="image tensor: values must lie in .*" + advice):
        calibrate(torch.from_numpy(image)[None].expand(3, -1, -1).contiguous())


# ------------------------------------------------------------------------------------------------------ tensors


def test_a_meta_tensor_is_one_clear_line():
    with pytest.raises(ImageReadError, match=r"^image tensor of shape \(3, 64, 64\) is on the meta device"):
        calibrate(torch.empty(3, 64, 64, device="meta"))


# ------------------------------------------------------------------------------------------------------ threads


def test_concurrent_decodes_leave_other_threads_stderr_alone(tmp_path, capfd, jpeg):
    """Decoding never redirects the process's stderr: every line another thread writes meanwhile reaches it."""
    import os

    (tmp_path / "a.jpg").write_bytes(jpeg)
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((96, 128, 3), np.uint8))
    done = threading.Event()

    def decode():
        while not done.is_set():
            read_image(tmp_path / "a.jpg")
            read_image(tmp_path / "b.png")

    readers = [threading.Thread(target=decode) for _ in range(3)]
    for reader in readers:
        reader.start()
    try:
        for i in range(400):
            os.write(2, f"line {i}\n".encode())
            time.sleep(0.0005)
    finally:
        done.set()
        for reader in readers:
            reader.join()
    lines = capfd.readouterr().err.splitlines()
    assert lines == [f"line {i}" for i in range(400)]


@pytest.mark.parametrize("ext", [".png", ".jpg", ".tif", ".webp", ".bmp"])
def test_decoded_images_are_writable_arrays_of_their_own(tmp_path, ext):
    """Callers turn the array into a tensor or draw on it: it must be writable (torch warns on read-only memory)."""
    path = tmp_path / f"a{ext}"
    cv2.imwrite(str(path), np.full((40, 50, 3), 7, np.uint8))
    rgb = read_image_file(path)
    assert rgb.flags.writeable and rgb.flags.c_contiguous and rgb.shape == (40, 50, 3)


# ------------------------------------------------------------------------------------------------- transparency


def _with_hidden_stripes(rgb: np.ndarray, stripes: bool) -> np.ndarray:
    """``rgb`` as RGBA, its left third under alpha 0 holding strong diagonal stripes (or the photo itself)."""
    rgba = np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])
    third = rgb.shape[1] // 3
    rgba[:, :third, 3] = 0
    if stripes:
        y, x = np.mgrid[: rgb.shape[0], :third]
        rgba[:, :third, :3] = np.where(((x + 2 * y) // 12 % 2 == 0)[..., None], 255, 0).astype(np.uint8)
    return rgba


def test_pixels_hidden_under_alpha_never_count(tmp_path):
    # hidden stripes once turned an upright building to roll 82.6 at confidence 0.93
    rgb = render_scene(2).image
    Image = pytest.importorskip("PIL.Image")
    for stripes in (False, True):
        Image.fromarray(_with_hidden_stripes(rgb, stripes), "RGBA").save(tmp_path / f"{stripes}.png")
    plain, striped = (read_image_file(tmp_path / f"{s}.png") for s in (False, True))
    assert np.array_equal(plain, striped) and (plain[:, : rgb.shape[1] // 3] == 128).all()
    assert np.array_equal(plain[:, rgb.shape[1] // 3 :], rgb[:, rgb.shape[1] // 3 :])  # the visible part as it is
    a, b = calibrate(str(tmp_path / "False.png")), calibrate(str(tmp_path / "True.png"))
    assert float(a.roll) == float(b.roll) and float(a.pitch) == float(b.pitch)
    assert np.array_equal(to_rgb_uint8(_with_hidden_stripes(rgb, True)), plain)  # arrays alike


def test_greyscale_and_palette_transparency_are_composited(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    grey = np.zeros((40, 40, 2), np.uint8)
    grey[..., 0], grey[:20, :, 1], grey[20:, :, 1] = 250, 0, 255  # the top half hidden
    Image.fromarray(grey, "LA").save(tmp_path / "la.png")
    palette = Image.fromarray(np.repeat(np.arange(40, dtype=np.uint8)[None] % 2, 40, 0), "P")
    palette.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)
    palette.save(tmp_path / "p.png", transparency=0)  # the red entry is transparent
    la, p = read_image_file(tmp_path / "la.png"), read_image_file(tmp_path / "p.png")
    assert (la[:20] == 128).all() and (la[20:] == 250).all()
    assert (p[:, 0::2] == 128).all() and (p[:, 1::2] == [0, 0, 255]).all()
    half = np.dstack([np.full((40, 40, 3), 200, np.uint8), np.full((40, 40), 128, np.uint8)])
    assert (to_rgb_uint8(half) == 164).all()  # (200 * 128 + 128 * 127) / 255, rounded
