"""The images of a folder or a list as items for ``ngp predict``: each read and its lines detected as
:func:`ngp_kornia.calibrate` does for a file, or the reason it could not be, and their batching."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor
from torch.utils.data import Dataset

from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.image_list import ImageList
from ngp_kornia.io import read_rgb_oriented
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.threads import Lookahead

__all__ = ["FolderImages", "FolderItem", "collate_items", "error_reason"]


class FolderItem(NamedTuple):
    """One image of the collection: its index in the collection, its name in its row and the (3, H, W) float image
    in [0, 1] with its line segments (1, N, 2, 2) and mask (1, N), or the reason it could not be read; and its
    file. An index of -1 is no image (a place that only evens out the processes' shares: it gets no row)."""

    index: int
    name: str
    image: Tensor | None
    error: str | None
    orientation: int | None = None
    segments: Tensor | None = None
    mask: Tensor | None = None
    path: str | None = None


class FolderImages(Dataset):
    """The images of an :class:`ImageList` (or an :class:`ImageFolder`) as :class:`FolderItem` records, each read
    and its lines detected as :func:`ngp_kornia.calibrate` does for a file; an unreadable file gives an item with its
    error instead of raising, so a run writes a row for every file.

    Args:
        images: the files.
        settings: the line-detection settings (:class:`SegmentSettings`; the defaults when None).
        stride: the step between the places one process asks for in turn (its DDP world size): the image it will
            ask for next is read on a second thread (:class:`~ngp_kornia.threads.Lookahead`) while the parser works
            on the current one; None reads each file only when asked (loader worker processes read ahead anyway).
        todo: the indices of the images to read, in order (None: all of them); place ``i`` is image ``todo[i]``.
        length: at least this many places, those past ``todo`` holding no image (index -1), so that each of
            ``length`` processes has one.
    """

    def __init__(
        self,
        images: ImageList | ImageFolder,
        settings: SegmentSettings | None = None,
        stride: int | None = 1,
        todo: Sequence[int] | None = None,
        length: int = 0,
    ) -> None:
        self.images = images if isinstance(images, ImageList) else ImageList.from_folder(images)
        self.settings = settings or SegmentSettings()
        self.stride = stride
        self.todo = range(len(self.images)) if todo is None else todo
        self.length = max(len(self.todo), length)
        self._ahead = Lookahead(self._read)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, place: int) -> FolderItem:
        if self.stride is None:
            return self._read(place)
        upcoming = place + self.stride
        return self._ahead.get(place, upcoming if upcoming < len(self) else None)

    def _read(self, place: int) -> FolderItem:
        if place >= len(self.todo):
            return FolderItem(-1, "", None, None)
        index = self.todo[place]
        name, path = self.images.names[index], self.images.path(index)
        try:
            rgb, orientation = read_rgb_oriented(path)
            segments, mask = detect_segments(rgb, self.settings)
        except Exception as err:  # whatever goes wrong with one file is that file's error row
            return FolderItem(index, name, None, error_reason(err, path), path=str(path))
        image = torch.from_numpy(rgb).permute(2, 0, 1).float().div(255.0)
        return FolderItem(index, name, image, None, orientation, segments, mask, str(path))

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
