"""The split of a folder of upright photos into a part to train on and two held back: fixed by each file's path."""

import cv2
import numpy as np
import pytest

from ngp_kornia.data.photo_split import PARTS, photo_part, split_photos


def _folder(tmp_path, count=40):
    for i in range(count):
        sub = tmp_path / ("a" if i % 2 else "b")
        sub.mkdir(exist_ok=True)
        cv2.imwrite(str(sub / f"{i:03d}.jpg"), np.full((8, 8, 3), i, np.uint8))
    return tmp_path


def test_every_photo_falls_in_exactly_one_part(tmp_path):
    root = _folder(tmp_path)
    parts = {part: split_photos(root, part) for part in PARTS}
    names = [n for ns in parts.values() for n in ns]
    assert len(names) == len(set(names)) == 40
    assert all("/" in n and not n.startswith("/") for n in names)  # relative, with / separators
    assert parts["train"] and len(parts["train"]) > len(parts["test"])


def test_the_part_follows_from_the_path_alone(tmp_path):
    root = _folder(tmp_path)
    before = split_photos(root, "test")
    cv2.imwrite(str(root / "a" / "new.jpg"), np.zeros((8, 8, 3), np.uint8))  # a photo added later moves no other
    after = split_photos(root, "test")
    assert [n for n in after if n != "a/new.jpg"] == before
    assert all(photo_part(n) == "test" for n in before)


def test_the_shares_are_about_six_one_one():
    parts = [photo_part(f"folder/photo_{i}.jpg") for i in range(4000)]
    shares = {part: parts.count(part) / len(parts) for part in PARTS}
    assert shares["train"] == pytest.approx(0.75, abs=0.03)
    assert shares["calibrate"] == pytest.approx(0.125, abs=0.02) and shares["test"] == pytest.approx(0.125, abs=0.02)


def test_an_unknown_part_is_refused(tmp_path):
    with pytest.raises(ValueError, match="part must be one of train, calibrate, test"):
        split_photos(tmp_path, "validation")
