"""A folder of unlabelled upright photos split by file into fixed parts: one to train on, two held back.

The orientation check learns from photos handed over the right way up (their four quarter turns are free labels). A
part of them must never be trained on: one part to calibrate the network's probabilities, one to test it. The part
of a photo follows from its path inside the folder alone (a hash), so it is the same on every machine, whatever
other files the folder holds, and a photo added later never moves another one.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ngp_kornia.data.folder import ImageFolder

__all__ = ["PARTS", "photo_part", "split_photos"]

#: the parts, and how many of eight photos fall in each (by the hash of their path)
PARTS = {"train": 6, "calibrate": 1, "test": 1}


def photo_part(name: str) -> str:
    """The part (``"train"``, ``"calibrate"`` or ``"test"``) of a photo, from its path inside the folder with
    ``/`` as separator: the first byte of the path's SHA-1 modulo 8 (six train, one calibrate, one test).

    Example:
        >>> photo_part("Urban100/img_001.jpg") in PARTS
        True
        >>> photo_part("Urban100/img_001.jpg") == photo_part("Urban100/img_001.jpg")
        True
    """
    slot = hashlib.sha1(name.encode()).digest()[0] % sum(PARTS.values())
    for part, count in PARTS.items():
        if slot < count:
            return part
        slot -= count
    raise AssertionError("unreachable: the slots cover every part")


def split_photos(root: str | Path, part: str) -> list[str]:
    """The photos of ``part`` in the folder ``root`` (searched recursively), as sorted paths relative to it.

    Raises:
        ValueError: ``part`` is not one of :data:`PARTS`.
        FileNotFoundError: ``root`` does not exist.
    """
    if part not in PARTS:
        raise ValueError(f"part must be one of {', '.join(PARTS)}, got {part!r}")
    return [name for name in ImageFolder(root, recursive=True).names if photo_part(name) == part]
