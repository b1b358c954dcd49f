"""Paths that are not readable regular files get one line that names the file and says what it is, for images and
for weights files alike."""

import os

import cv2
import numpy as np
import pytest

from ngp_kornia import calibrate
from ngp_kornia.errors import ImageReadError, WeightsError
from ngp_kornia.io import header_size, open_file
from ngp_kornia.nets.weights import load_network


def _fifo(path):
    if not hasattr(os, "mkfifo"):
        pytest.skip("no named pipes on this system")
    os.mkfifo(path)
    return path


def _loop(path):
    os.symlink(path.name, path)  # a link to itself
    return path


def _directory(path):
    path.mkdir()
    return path


def _dangling(path):
    os.symlink(path.parent / "gone.file", path)
    return path


CASES = [
    (_fifo, r"is a named pipe \(FIFO\), expected an? (image|weights) file"),
    (_loop, "a symbolic link that loops back on itself"),
    (_directory, "is a directory, expected an? (image|weights) file"),
    (_dangling, r"file not found \(a symbolic link to .*gone.file, which does not exist\)"),
]


@pytest.mark.parametrize("make, message", CASES, ids=["fifo", "loop", "directory", "dangling"])
def test_an_image_path_that_is_no_regular_file_says_what_it_is(tmp_path, make, message):
    path = make(tmp_path / "photo.jpg")
    with pytest.raises(ImageReadError, match=f"^{path}: {message}") as caught:
        calibrate(path)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("make, message", CASES, ids=["fifo", "loop", "directory", "dangling"])
def test_a_weights_path_that_is_no_regular_file_says_what_it_is(tmp_path, make, message):
    path = make(tmp_path / "x.pt")
    with pytest.raises(WeightsError, match=f"^{path}: {message}"):
        load_network(path, "ZSNet")


def test_a_missing_file_is_not_found_and_a_real_one_opens(tmp_path):
    with pytest.raises(ValueError, match="nope.png: file not found"):
        open_file(tmp_path / "nope.png", ValueError, "image file")
    path = tmp_path / "a.png"
    assert cv2.imwrite(str(path), np.zeros((40, 50, 3), np.uint8))
    file, size = open_file(path, ValueError, "image file")
    with file:
        data = file.read()
    assert size == len(data) == path.stat().st_size and header_size(data) == (40, 50)


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tif", ".webp", ".ppm"])
def test_header_size_of_every_format_read(ext):
    ok, data = cv2.imencode(ext, np.zeros((37, 53, 3), np.uint8))
    assert header_size(data.tobytes()) == (37, 53)
    assert header_size(data.tobytes()[:6]) is None and header_size(b"not an image") is None


@pytest.mark.parametrize(
    "path, message",
    [
        ("", "^an empty path was given where an image file was expected$"),
        ("~/no-such-photo.png", r"'~' is not expanded here; pass os.path.expanduser\(path\)"),
        ("https://example.com/a.jpg", "^https://example.com/a.jpg: addresses are not downloaded"),
    ],
)
def test_paths_a_user_may_mean_otherwise_are_named_as_given(path, message):
    with pytest.raises(ImageReadError, match=message):
        calibrate(path)
