"""The images of a folder, in a fixed order, for prediction.

Files are matched by extension (case-insensitive) and sorted by their path relative to the folder, so the order
does not depend on the file system. Hidden files and folders (names starting with ``"."``, such as macOS ``._``
resource forks) are skipped. An unreadable file is not skipped: :meth:`ImageFolder.safe_load` reports it, so a
prediction run can write a row for every file.
"""

from __future__ import annotations

import operator
import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from torch import Tensor

from ngp_kornia.io import ImageError, load_image

__all__ = ["IMAGE_EXTENSIONS", "ImageFolder"]

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def _normalize_extensions(extensions: Iterable[str]) -> frozenset[str]:
    if isinstance(extensions, str):
        extensions = [extensions]
    out = set()
    for ext in extensions:
        if not isinstance(ext, str) or not ext.strip(".").strip():
            raise ValueError(f"extensions must be non-empty strings such as '.jpg' or 'png', got {ext!r}")
        out.add("." + ext.strip().lstrip(".").lower())
    if not out:
        raise ValueError("extensions is empty; give at least one, e.g. ('.jpg', '.png')")
    return frozenset(out)


def _is_hidden(name: str) -> bool:
    return name.startswith(".")


def _list_files(root: Path, recursive: bool) -> Iterator[Path]:
    if not recursive:
        yield from (p for p in root.iterdir() if not _is_hidden(p.name))
        return
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if not _is_hidden(d)]
        yield from (Path(folder) / f for f in files if not _is_hidden(f))


def _broken_link(path: Path) -> bool:
    return path.is_symlink() and not path.exists()


class ImageFolder(Sequence[tuple[Path, Tensor]]):
    """The image files of a folder as a sorted sequence of ``(path, image)``.

    Args:
        root: the folder.
        recursive: also list the files of sub-folders (symbolic links to folders are not followed).
        extensions: file name endings to keep, case-insensitive, with or without the dot.

    Raises:
        FileNotFoundError: ``root`` does not exist.
        NotADirectoryError: ``root`` is a file.
        ValueError: empty or invalid extensions.

    Usage::

        images = ImageFolder("photos", recursive=True)
        for i in range(len(images)):
            path, image, error = images.safe_load(i)  # image (3, H, W) in [0, 1], or None and a message

    Example:
        >>> ImageFolder("/no/such/folder")
        Traceback (most recent call last):
        ...
        FileNotFoundError: image folder not found: /no/such/folder
    """

    def __init__(
        self, root: str | Path, recursive: bool = False, extensions: Iterable[str] = IMAGE_EXTENSIONS
    ) -> None:
        self.root = Path(root)
        if not self.root.exists():
            raise FileNotFoundError(f"image folder not found: {self.root}")
        if not self.root.is_dir():
            raise NotADirectoryError(f"expected a folder of images, got a file: {self.root}; pass its folder")
        self.recursive = bool(recursive)
        self.extensions = _normalize_extensions(extensions)
        found = (p for p in _list_files(self.root, self.recursive) if p.suffix.lower() in self.extensions)
        # a link to nothing is listed, so its row says so instead of the image vanishing from the results
        self.paths: list[Path] = sorted((p for p in found if p.is_file() or _broken_link(p)), key=self._sort_key)

    def _sort_key(self, path: Path) -> tuple[str, ...]:
        return path.relative_to(self.root).parts

    @property
    def names(self) -> list[str]:
        """The paths relative to ``root``, with ``/`` separators."""
        return [p.relative_to(self.root).as_posix() for p in self.paths]

    def __len__(self) -> int:
        return len(self.paths)

    def _path(self, index: int) -> Path:
        try:
            index = operator.index(index)
        except TypeError:
            raise TypeError(f"index must be an integer, got {type(index).__name__}") from None
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for a folder of {len(self)} images")
        return self.paths[index]

    def __getitem__(self, index: int) -> tuple[Path, Tensor]:  # type: ignore[override]
        """``(path, image)`` with the image a (3, H, W) float tensor in [0, 1].

        Raises:
            ImageError: the file cannot be decoded, or is smaller than :data:`ngp_kornia.io.MIN_SIZE` pixels.
        """
        path = self._path(index)
        return path, load_image(path)[0]

    def safe_load(self, index: int) -> tuple[Path, Tensor | None, str | None]:
        """``(path, image, None)``, or ``(path, None, message)`` when the file cannot be read."""
        path = self._path(index)
        try:
            return path, load_image(path)[0], None
        except ImageError as err:
            return path, None, str(err)
        except OSError as err:  # permissions, a file removed since listing, ...
            return path, None, f"{path}: cannot read the file: {err.strerror or err}"

    def __iter__(self) -> Iterator[tuple[Path, Tensor]]:
        return (self[i] for i in range(len(self)))

    def __repr__(self) -> str:
        return f"ImageFolder(root={str(self.root)!r}, recursive={self.recursive}, images={len(self)})"
