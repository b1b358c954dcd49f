"""The files of a folder as items for ``ngp predict``: each read and its lines detected as
:func:`ngp_kornia.calibrate` does for a file, or the reason it could not be, and their batching."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor
from torch.utils.data import Dataset

from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.io import read_rgb_oriented
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.threads import Lookahead

__all__ = ["FolderImages", "FolderItem", "collate_items", "error_reason"]


class FolderItem(NamedTuple):
    """One file of the folder: its dataset index, its path relative to the folder, and the (3, H, W) float image
    in [0, 1] with its line segments (1, N, 2, 2) and mask (1, N), or the reason it could not be read."""

    index: int
    name: str
    image: Tensor | None
    error: str | None
    orientation: int | None = None
    segments: Tensor | None = None
    mask: Tensor | None = None


class FolderImages(Dataset):
    """The files of an :class:`ImageFolder` as :class:`FolderItem` records, each read and its lines detected as
    :func:`ngp_kornia.calibrate` does for a file; an unreadable file gives an item with its error instead of raising,
    so a run writes a row for every file.

    Args:
        folder: the files.
        settings: the line-detection settings (:class:`SegmentSettings`; the defaults when None).
        stride: the step between the indices one process asks for in turn (its DDP world size): the file it will
            ask for next is read on a second thread (:class:`~ngp_kornia.threads.Lookahead`) while the parser works
            on the current one; None reads each file only when asked (loader worker processes read ahead anyway).
    """

    def __init__(self, folder: ImageFolder, settings: SegmentSettings | None = None, stride: int | None = 1) -> None:
        self.folder = folder
        self.settings = settings or SegmentSettings()
        self.stride = stride
        self._ahead = Lookahead(self._read)

    def __len__(self) -> int:
        return len(self.folder)

    def __getitem__(self, index: int) -> FolderItem:
        if self.stride is None:
            return self._read(index)
        upcoming = index + self.stride
        return self._ahead.get(index, upcoming if upcoming < len(self) else None)

    def _read(self, index: int) -> FolderItem:
        path = self.folder.paths[index]
        name = path.relative_to(self.folder.root).as_posix()
        try:
            rgb, orientation = read_rgb_oriented(path)
            segments, mask = detect_segments(rgb, self.settings)
        except Exception as err:  # whatever goes wrong with one file is that file's error row
            return FolderItem(index, name, None, error_reason(err, path))
        image = torch.from_numpy(rgb).permute(2, 0, 1).float().div(255.0)
        return FolderItem(index, name, image, None, orientation, segments, mask)

    def close(self) -> None:
        """Stop reading ahead."""
        self._ahead.close()


def error_reason(err: BaseException, path) -> str:
    """One line for an error row: the message, naming the file."""
    text = " ".join(str(err).split()) or type(err).__name__
    if isinstance(err, OSError) and err.strerror:
        text = f"cannot read the file: {err.strerror}"
    elif not isinstance(err, ValueError):
        text = f"{type(err).__name__}: {text}"
    return text if str(path) in text else f"{path}: {text}"


def collate_items(items: list[FolderItem]) -> list[FolderItem]:
    """Keep a batch as a list: the images of a folder may all differ in size."""
    return items
