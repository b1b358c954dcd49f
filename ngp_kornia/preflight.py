"""Checks the ``ngp`` and ``ngp-train`` commands make before they import torch, OpenCV or Lightning (seconds): an
optional dependency that is not installed, a folder that holds no image, a file that is not a COLMAP database. They
import nothing but the standard library (and the package's errors), so a wrong argument is answered at once.

Example:
    >>> from ngp_kornia.preflight import check_extra
    >>> check_extra(["json"], "this example", "train")  # installed: nothing to say
"""

from __future__ import annotations

import importlib.util
import os
import sqlite3
from collections.abc import Iterable, Iterator
from pathlib import Path

from ngp_kornia.errors import OutputError

__all__ = ["COLMAP_TABLES", "IMAGE_EXTENSIONS", "check_database", "check_extra", "check_folder", "image_files",
           "same_file"]

#: the file endings of a folder's images: those of :class:`ngp_kornia.data.folder.ImageFolder`, which imports torch
#: (a test keeps the two the same)
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
#: the tables a COLMAP database has (an existing file without them is not one, and is refused)
COLMAP_TABLES = ("cameras", "images")


def check_extra(modules: Iterable[str], needed_by: str, extra: str) -> None:
    """Say which extra to install when a top-level module is missing, without importing any of them.

    Args:
        modules: top-level module names, e.g. ``["lightning", "jsonargparse"]``.
        needed_by: what needs them, for the message (``"ngp predict"``).
        extra: the package's extra that brings them (``"train"``).

    Raises:
        ImportError: one is not installed; the message names the install command.
    """
    missing = [name for name in modules if not _installed(name)]
    if missing:
        names = " and ".join(missing)
        raise ImportError(f"{needed_by} needs {names}, not installed here: pip install 'ngp-kornia[{extra}]'")


def _installed(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a module that cannot be found, or a broken entry in sys.modules
        return False


def _listed(path: Path) -> bool:
    """A file, or a link to nothing (listed so that its row says so)."""
    return path.is_file() or (path.is_symlink() and not path.exists())


def image_files(folder: Path, recursive: bool) -> Iterator[Path]:
    """The image files of a folder as :class:`~ngp_kornia.data.folder.ImageFolder` lists them (by extension,
    case-insensitive; hidden files and folders skipped; links to folders not followed), in the order found."""
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".")] if recursive else []
        for name in files:
            path = Path(root) / name
            if not name.startswith(".") and path.suffix.lower() in IMAGE_EXTENSIONS and _listed(path):
                yield path


def check_folder(folder: str | Path, recursive: bool = False) -> None:
    """Refuse a folder to calibrate that does not exist, is a file, or holds no image file.

    Raises:
        FileNotFoundError: no such folder.
        NotADirectoryError: a file.
        ValueError: no image file in it (nor, with ``recursive``, below it).
    """
    folder = Path(folder)
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such folder; give the folder that holds the images")
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: is a file, not a folder; for single images use ngp calibrate")
    if next(image_files(folder, recursive), None) is None:
        hint = "" if recursive else "; use --recursive for images in sub-folders"
        raise ValueError(f"{folder}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)}){hint}")


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two names are one file: the same path once links are resolved, or hard links of one file (False
    where either cannot be looked at).

    Example:
        >>> same_file(".", "./")
        True
    """
    try:
        return Path(a).resolve() == Path(b).resolve() or os.path.samefile(a, b)
    except OSError:
        return False


def check_database(database: str | Path) -> Path:
    """Refuse a path that is not a COLMAP database and would be changed by opening it as one.

    A missing or empty file is fine (a new database is made); an existing file must be an SQLite database with
    COLMAP's tables (``cameras``, ``images``): anything else (a photo, a results file, another program's SQLite file,
    a folder) is refused, never written to.

    Args:
        database: the path given for the database.

    Returns:
        the path, as a :class:`~pathlib.Path`.

    Raises:
        OutputError: with the fix in the message.

    Example:
        >>> check_database(getfixture("tmp_path") / "new.db").name
        'new.db'
    """
    path = Path(database)
    if path.is_dir():
        raise OutputError(f"{path} is a folder; give the COLMAP database file, e.g. {path / 'database.db'}")
    if not path.exists() or path.stat().st_size == 0:
        return path
    refused = OutputError(f"{path} exists and is not a COLMAP database, so it would be changed; give another file "
                          "or a database COLMAP made")
    try:
        with path.open("rb") as file:
            if file.read(16) != b"SQLite format 3\x00":
                raise refused
        connection = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
        try:
            tables = {r[0] for r in connection.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        finally:
            connection.close()
    except (OSError, sqlite3.Error) as err:
        raise OutputError(f"{path} cannot be read as a COLMAP database ({err}); give another file") from None
    if not set(COLMAP_TABLES) <= tables:
        raise refused
    return path
