"""Training data of the line reader (:class:`~ngp_kornia.nets.upright_lines.UprightLinesNet`): the line segments of
upright photos, each photo shown in its four quarter turns (the labels), and in training also in those of its mirror
image, which is as upright as the photo.

The segments are detected once per photo, on the upright photo, with the parser's detection at its default settings
(:func:`~ngp_kornia.pipeline.segments.detect_segments`), and cached on disk like the other training sets
(:class:`~ngp_kornia.training.scene_data.CachedScenes`, keyed by the folder, the photos and the settings). A turn or a
mirror moves the segments exactly (:func:`~ngp_kornia.nets.upright_lines.turn_segments`,
:func:`~ngp_kornia.nets.upright_lines.mirror_segments`), so no photo is read or detected again for it. The photos are
split by file (:mod:`ngp_kornia.data.photo_split`): the ``train`` part trains, the ``calibrate`` part validates (and
is where the temperature and the fusion weights are fitted afterwards, :mod:`ngp_kornia.training.upright_lines_fit`),
the ``test`` part is for reports only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.errors import ConfigError
from ngp_kornia.io import read_image_file
from ngp_kornia.nets.upright_lines import mirror_segments, turn_segments
from ngp_kornia.pipeline.segments import detect_segments, pad_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.training.datamodules import SceneDataModule
from ngp_kornia.training.scene_data import CachedScenes

__all__ = ["LineBatch", "LineSample", "PhotoSegments", "TurnedViews", "UprightLinesDataModule", "collate_lines"]


@dataclass
class LineSample:
    """The (N, 2, 2) float32 segments of one image in its pixels and its (2,) ``(height, width)``; in a view also its
    (1,) turn (quarter turns counter-clockwise from upright)."""

    segments: np.ndarray
    image_size: np.ndarray
    turn: np.ndarray | None = None


@dataclass
class LineBatch:
    """Segments (B, N, 2, 2) in pixels, padded (N at least 1), their (B, N) bool mask, the (B, 2) ``(height,
    width)`` of each view and its (B,) turn."""

    segments: Tensor
    mask: Tensor
    image_size: Tensor
    turns: Tensor

    def __len__(self) -> int:
        return len(self.segments)


def collate_lines(samples: list[LineSample]) -> LineBatch:
    segments, mask = pad_segments([s.segments for s in samples] + [np.zeros((1, 2, 2), np.float32)])
    size = torch.from_numpy(np.stack([s.image_size for s in samples])).long()
    turns = torch.from_numpy(np.concatenate([s.turn for s in samples])).long()
    return LineBatch(segments[:-1], mask[:-1], size, turns)  # the empty extra row keeps N >= 1 for the readers' max


class PhotoSegments(CachedScenes):
    """The segments of upright photos in a folder; key ``p12`` is the 12th of ``names`` (paths relative to
    ``root``).

    Args:
        root: the photo folder.
        names: the photos, relative to ``root``.
        cache_dir: cache root (None: detect every time).
        settings: the detection settings (None: the parser's defaults, as the reader is used).
    """

    sample_type = LineSample

    def __init__(
        self,
        root: str | Path,
        names: list[str],
        cache_dir: str | Path | None = None,
        settings: SegmentSettings | None = None,
    ) -> None:
        self.root, self.names = str(root), list(names)
        self.settings = settings or SegmentSettings()
        spec = {"root": str(Path(root).resolve()), "names": self.names, "settings": asdict(self.settings), "v": 1}
        super().__init__([f"p{i}" for i in range(len(self.names))], "line-segments", spec, cache_dir=cache_dir)

    def compute(self, key: str) -> LineSample:
        rgb = read_image_file(f"{self.root}/{self.names[int(key[1:])]}")
        segments, mask = detect_segments(rgb, self.settings)
        return LineSample(segments[0][mask[0]].numpy().astype(np.float32), np.array(rgb.shape[:2], np.int64))


class TurnedViews(Dataset):
    """Every photo of a :class:`PhotoSegments` in its four turns (``np.rot90``'s sense), photo by photo, and with
    ``mirrors`` also the four turns of its mirror image: ``keys`` are ``(photo, turn, mirrored)``.

    Args:
        photos: the photos' segments.
        mirrors: add the mirror images' turns.
    """

    def __init__(self, photos: PhotoSegments, mirrors: bool) -> None:
        self.photos = photos
        flips = (False, True) if mirrors else (False,)
        self.keys = [(i, k, m) for i in range(len(photos)) for m in flips for k in range(4)]

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, index: int) -> LineSample:
        photo, turn, mirrored = self.keys[index]
        sample = self.photos[photo]
        height, width = (int(v) for v in sample.image_size)
        segments = torch.from_numpy(sample.segments)
        if mirrored:
            segments = mirror_segments(segments, width)
        segments, height, width = turn_segments(segments, height, width, turn)
        return LineSample(segments.numpy(), np.array([height, width], np.int64), np.array([turn], np.int64))

    def prepare(self, workers: int = 0, progress: bool | None = None) -> None:
        """Detect the segments of the photos the views use (all of them, unless the keys were cut)."""
        keys = self.photos.keys
        self.photos.keys = [keys[i] for i in sorted({photo for photo, _, _ in self.keys})]
        try:
            self.photos.prepare(workers, progress)
        finally:
            self.photos.keys = keys


class UprightLinesDataModule(SceneDataModule):
    """The views of a folder of upright photos (:func:`~ngp_kornia.data.photo_split.split_photos`): its ``train``
    part in four turns of the photo and of its mirror image (training), the ``calibrate`` part (validation) and the
    ``test`` part (test) in four turns.

    Args:
        photos: the folder of upright photos (searched recursively).
        cache_dir: on-disk cache folder of the detected segments (None: no cache).
        batch_size: views per batch.
        num_workers: loader worker processes (also used to fill the cache).

    Example:
        >>> UprightLinesDataModule(photos=None).setup("fit")
        Traceback (most recent call last):
        ...
        ngp_kornia.errors.ConfigError: no photo folder: give data.photos, e.g. --data.init_args.photos RealPhotos
    """

    collate = staticmethod(collate_lines)

    def __init__(
        self, photos: str | None = None, cache_dir: str | None = "cache", batch_size: int = 256, num_workers: int = 0
    ) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, TurnedViews]:
        hp = self.hparams
        if hp.photos is None:
            raise ConfigError("no photo folder: give data.photos, e.g. --data.init_args.photos RealPhotos")
        if not Path(hp.photos).is_dir():
            raise ConfigError(f"photo folder not found: {hp.photos}; give data.photos a folder of upright photos")
        out = {}
        for name, part in (("train", "train"), ("val", "calibrate"), ("test", "test")):
            names = split_photos(hp.photos, part)
            if not names and name != "test":
                raise ConfigError(f"{hp.photos} has no photo in its {part} part; it needs more photos (one in eight "
                                  "falls in the calibrate part)")  # fmt: skip
            out[name] = TurnedViews(PhotoSegments(hp.photos, names, hp.cache_dir), mirrors=name == "train")
        return out
