r"""The images of a collection given as a list file, for ``ngp predict --list FILE``; and a folder's images in the
same form.

A list file is either

* a text file of one path per line (UTF-8; blank lines skipped, spaces around a path dropped), or
* a CSV file (its name ends in ``.csv``) whose first line names the columns: the paths are in its ``path``
  column, or else its ``image`` column (case-insensitive); every other column is left alone, so a manifest of
  labels (:class:`~ngp_kornia.data.manifest.CSVManifest`) serves as a list as it is.

A relative path is relative to the list file's folder, an absolute one stands as it is (so one list may name files
on several disks), and a leading ``~`` is the home folder. The files are not filtered by extension, and checked only
so far as one of them must exist (else the paths are most likely relative to another folder): a file that is
missing or cannot be read becomes its error row when it is calibrated. Each image may be listed once only.

Example:
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     listed = Path(tmp, "photos.txt")
    ...     _ = listed.write_text("a.jpg\n\n  street/b.png\n/mnt/disk2/c.jpg\n")
    ...     Path(tmp, "a.jpg").touch()
    ...     images = read_image_list(listed)
    ...     images.names, images.path(1) == Path(tmp, "street/b.png"), str(images.path(2))
    (['a.jpg', 'street/b.png', '/mnt/disk2/c.jpg'], True, '/mnt/disk2/c.jpg')
"""

from __future__ import annotations

import csv
import hashlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.manifest import ManifestError

__all__ = ["PATH_COLUMNS", "ImageList", "read_image_list"]

#: the CSV columns that hold the paths, the first one found
PATH_COLUMNS = ("path", "image")


@dataclass(frozen=True)
class ImageList:
    """The images of a collection, in the order their rows are written: ``names[i]`` is the image's name in its row
    (a folder's images: their paths relative to the folder; a list's: the paths as listed) and its file is
    ``root / names[i]`` (an absolute name is the file itself).

    Attributes:
        root: the folder the names are relative to.
        names: one per image, no two the same.
        source: what the images came from (the folder or the list file), for messages.
    """

    root: Path
    names: list[str]
    source: Path

    @classmethod
    def from_folder(cls, folder: ImageFolder) -> ImageList:
        """The images of an :class:`ImageFolder`, in its order."""
        return cls(folder.root, folder.names, folder.root)

    def __len__(self) -> int:
        return len(self.names)

    def path(self, index: int) -> Path:
        """The file of image ``index``."""
        return self.root / self.names[index]

    @property
    def paths(self) -> Iterator[Path]:
        """The files, in order (made one at a time)."""
        return (self.root / name for name in self.names)

    def fingerprint(self) -> str:
        """A digest of the files (the root as an absolute path, and the names): two runs over the same images in
        the same order have the same one."""
        digest = hashlib.sha256(os.path.abspath(self.root).encode("utf-8", "surrogateescape") + b"\0")
        for name in self.names:
            digest.update(name.encode("utf-8", "surrogateescape") + b"\n")
        return digest.hexdigest()


def read_image_list(path: str | Path) -> ImageList:
    """The images a list file names (format: see the module docstring).

    Args:
        path: the list file, text (one path per line) or CSV (``.csv``, with a ``path`` or ``image`` column).

    Returns:
        the :class:`ImageList`, its root the list file's folder.

    Raises:
        FileNotFoundError: no such list file, or none of the files it lists exists.
        IsADirectoryError: a folder was given (give the folder itself as the argument instead).
        ManifestError: not UTF-8, a CSV without a path column, no path in it, or an image listed twice (naming
            both lines).
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"--list {path} is a folder; give it as the folder argument, or give a list file")
    if not path.is_file():
        raise FileNotFoundError(f"--list {path}: no such file; give a text file of one image path per line")
    lines = _csv_lines(path) if path.suffix.lower() == ".csv" else _text_lines(path)
    names: list[str] = []
    first: dict[str, int] = {}
    for line, text in lines:
        name = os.path.expanduser(text) if text.startswith("~") else text
        if (earlier := first.setdefault(name, line)) != line:
            raise ManifestError(f"{path}, line {line}: {text} is listed on line {earlier} already; list it once")
        names.append(name)
    if not names:
        raise ManifestError(f"{path} lists no image; give one image path per line (or a CSV with a path column)")
    images = ImageList(path.parent, names, path)
    if not any(file.exists() or file.is_symlink() for file in images.paths):  # stops at the first that exists
        raise FileNotFoundError(
            f"{path}: none of its {len(names)} listed files exists (relative paths are taken from the list's "
            f"folder {path.parent}), e.g. {names[0]}"
        )
    return images


def _decoded(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as err:
        raise ManifestError(f"{path}: not a UTF-8 text file ({err}); save the list as UTF-8") from None


def _text_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, path) of the lines that are not blank."""
    for number, line in enumerate(_decoded(path), start=1):
        if line.strip():
            yield number, line.strip()


def _csv_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, path) of the CSV rows whose path cell is not empty."""
    try:
        reader = csv.reader(_decoded(path))
        header = [name.strip().lower() for name in next(reader, [])]
        column = next((header.index(name) for name in PATH_COLUMNS if name in header), None)
        if column is None:
            raise ManifestError(
                f"{path}, line 1: no 'path' or 'image' column (header: {header}); name the column of the image "
                "paths 'path', or give a text file of one path per line"
            )
        for row in reader:
            cell = row[column].strip() if column < len(row) else ""
            if cell:
                yield reader.line_num, cell
    except csv.Error as err:
        raise ManifestError(f"{path}: malformed CSV: {err}") from None
