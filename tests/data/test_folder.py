import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.data.folder import IMAGE_EXTENSIONS, ImageFolder
from ngp_kornia.io import ImageError


def _image(path: Path, value: int = 100, size=(40, 48)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.full((*size, 3), value, np.uint8))
    return path


@pytest.fixture()
def folder(tmp_path: Path) -> Path:
    _image(tmp_path / "b.png", 10)
    _image(tmp_path / "A.JPG", 200)
    _image(tmp_path / "c.jpeg")
    _image(tmp_path / "sub" / "d.png")
    _image(tmp_path / "sub" / "deeper" / "e.bmp")
    _image(tmp_path / ".hidden" / "f.png")
    _image(tmp_path / "._resource.jpg")
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (tmp_path / "empty.jpg").write_bytes(b"")
    (tmp_path / "garbage.webp").write_bytes(b"0123456789" * 10)
    _image(tmp_path / "tiny.png", size=(8, 8))
    (tmp_path / "folder.jpg").mkdir()
    return tmp_path


def test_sorted_and_filtered(folder):
    flat = ImageFolder(folder)
    assert flat.names == ["A.JPG", "b.png", "broken.png", "c.jpeg", "empty.jpg", "garbage.webp", "tiny.png"]
    assert flat.paths[0] == folder / "A.JPG" and len(flat) == 7
    deep = ImageFolder(folder, recursive=True)
    assert deep.names == flat.names[:6] + ["sub/d.png", "sub/deeper/e.bmp", "tiny.png"]
    assert ImageFolder(folder, recursive=True, extensions=["PNG", ".bmp"]).names == [
        "b.png",
        "broken.png",
        "sub/d.png",
        "sub/deeper/e.bmp",
        "tiny.png",
    ]
    assert ImageFolder(folder, extensions=".jpeg").names == ["c.jpeg"]
    assert ".png" in IMAGE_EXTENSIONS and "images=7" in repr(flat)


def test_getitem_returns_float_rgb(folder):
    images = ImageFolder(folder)
    path, image = images[1]
    assert path == folder / "b.png"
    assert image.shape == (3, 40, 48) and image.dtype == torch.float32
    assert torch.allclose(image, torch.full_like(image, 10 / 255))
    assert images[-7][0] == folder / "A.JPG" and images[np.int64(0)][0] == folder / "A.JPG"
    with pytest.raises(IndexError):
        images[7]
    with pytest.raises(TypeError):
        images["b.png"]
    with pytest.raises(ImageError, match="broken.png"):
        images[2]


def test_safe_load_reports_every_file(folder):
    images = ImageFolder(folder)
    rows = [images.safe_load(i) for i in range(len(images))]
    assert [r[0].name for r in rows] == images.names
    ok = {r[0].name for r in rows if r[1] is not None}
    assert ok == {"A.JPG", "b.png", "c.jpeg"}
    errors = {r[0].name: r[2] for r in rows if r[1] is None}
    assert "truncated" in errors["broken.png"]
    assert "not a readable image" in errors["garbage.webp"]
    assert "file is empty" in errors["empty.jpg"]
    assert "at least 32 px" in errors["tiny.png"]
    assert all(r[2] is None for r in rows if r[1] is not None)
    assert len(list(iter(ImageFolder(folder / "sub")))) == 1


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="needs file permissions")
def test_safe_load_unreadable_file(tmp_path):
    path = _image(tmp_path / "locked.png")
    path.chmod(0)
    try:
        _, image, error = ImageFolder(tmp_path).safe_load(0)
    finally:
        path.chmod(0o644)
    assert image is None and "locked.png" in error


def test_safe_load_os_error(tmp_path, monkeypatch):
    _image(tmp_path / "x.png")
    images = ImageFolder(tmp_path)

    def denied(path):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("ngp_kornia.data.folder.load_image", denied)
    path, image, error = images.safe_load(0)
    assert image is None and error == f"{path}: cannot read the file: Permission denied"


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="image folder not found"):
        ImageFolder(tmp_path / "none")
    with pytest.raises(NotADirectoryError, match="pass its folder"):
        ImageFolder(_image(tmp_path / "x.png"))
    with pytest.raises(ValueError, match="extensions"):
        ImageFolder(tmp_path, extensions=[])
    with pytest.raises(ValueError, match="extensions"):
        ImageFolder(tmp_path, extensions=["."])
    assert len(ImageFolder(tmp_path, extensions=["gif"])) == 0


def test_a_link_to_nothing_is_listed_and_reported(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.full((40, 40, 3), 90, np.uint8))
    (tmp_path / "gone.png").symlink_to(tmp_path / "moved-away.png")
    ds = ImageFolder(tmp_path)
    assert ds.names == ["a.png", "gone.png"]
    path, image, error = ds.safe_load(1)
    assert image is None and "moved-away.png, which does not exist" in error
