"""Training data of the orientation and structure check (:class:`~ngp_kornia.nets.upright.UprightNet`): thumbnails
of real photos handed over upright, of renders and of structure-free images (all upright; the module turns them),
cached on disk like the other training sets (:class:`~ngp_kornia.training.scene_data.CachedScenes`).

Real photos teach what renders cannot (how real rooms, streets and things look the right way up); they are split by
file (:mod:`ngp_kornia.data.photo_split`): the ``train`` part is trained on, the ``calibrate`` part validates (each
photo turned four ways) and is where the probabilities are calibrated, the ``test`` part is for reports only.
Whether a real photo shows man-made structure is not known, so it teaches only the turn. Renders come in three
shapes (landscape 4:3, portrait 3:4, square) so that a photo's shape says nothing about how it is turned. Every
``structureless_every``-th render sample is a structure-free image
(:func:`~ngp_kornia.training.synth.structureless.structureless_image`) instead of a render. Thumbnails are cached
at ``store_size`` (at least the network's size), so that training can crop them before it averages them down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.io import read_image_file
from ngp_kornia.nets.upright import thumbnail
from ngp_kornia.training.datamodules import RenderedDataModule, SceneDataModule
from ngp_kornia.training.scene_data import CachedScenes, JoinedScenes
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig, config_spec
from ngp_kornia.training.synth.structureless import structureless_image

__all__ = [
    "STRUCTURELESS_SEEDS",
    "PhotoThumbs",
    "ThumbBatch",
    "ThumbSample",
    "UprightDataModule",
    "UprightThumbs",
    "collate_thumbs",
]

#: first seeds of the structure-free images of the training and validation sets (the test images of
#: ``benchmarks/out_of_world.py`` draw from 5,000,000)
STRUCTURELESS_SEEDS = {"train": 4_000_000, "val": 4_500_000, "test": 4_700_000}
#: rendered shapes ``(W, H)``, drawn by seed
SHAPES = ((640, 480), (640, 480), (640, 480), (480, 640), (480, 640), (512, 512))


@dataclass
class ThumbSample:
    """One upright thumbnail (3, S, S) uint8, whether it shows structure (1) or not (0), and whether it is a real
    photo (1), whose structure is not known, or a render or structure-free image (0)."""

    thumb: np.ndarray
    structured: np.ndarray
    real: np.ndarray


@dataclass
class ThumbBatch:
    """Thumbnails (B, 3, S, S) float in [0, 1], (B,) bool structure flags and (B,) bool real-photo flags."""

    thumbs: Tensor
    structured: Tensor
    real: Tensor

    def __len__(self) -> int:
        return len(self.thumbs)


def collate_thumbs(samples: list[ThumbSample]) -> ThumbBatch:
    thumbs = torch.from_numpy(np.stack([s.thumb for s in samples])).float() / 255.0
    structured, real = (torch.from_numpy(np.stack([getattr(s, k) for s in samples])).bool().reshape(-1)
                        for k in ("structured", "real"))  # fmt: skip
    return ThumbBatch(thumbs, structured, real)


def thumb_of(rgb: np.ndarray, size: int) -> np.ndarray:
    """The (3, size, size) uint8 thumbnail of an (H, W, 3) uint8 image, as the parser makes it."""
    image = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float() / 255.0
    return (thumbnail(image, size)[0] * 255.0).round().clamp(0, 255).byte().numpy()


class UprightThumbs(CachedScenes):
    """Render and structure-free thumbnails; keys ``("r", seed)`` or ``("s", seed)`` written as ``r12`` / ``s12``.

    Args:
        keys: the samples' keys.
        size: thumbnail side.
        config: renderer settings.
        cache_dir: cache root (None: compute every time).
    """

    sample_type = ThumbSample

    def __init__(self, keys: list[str], size: int = 64, config: RenderConfig | None = None,
                 cache_dir: str | None = None) -> None:
        self.size, self.config = size, config or RenderConfig()
        spec = {"size": size, "cfg": config_spec(self.config), "shapes": SHAPES, "v": 2}
        super().__init__(keys, f"upright-{size}", spec, cache_dir=cache_dir)

    def compute(self, key: str) -> ThumbSample:
        seed = int(key[1:])
        if key[0] == "s":
            shape = SHAPES[seed % len(SHAPES)]
            return ThumbSample(thumb_of(structureless_image(seed, shape), self.size), *_flags(0, 0))
        image = render_scene(seed, SHAPES[seed % len(SHAPES)], self.config).image
        return ThumbSample(thumb_of(image, self.size), *_flags(1, 0))


def _flags(structured: int, real: int) -> tuple[np.ndarray, np.ndarray]:
    return np.array([structured], np.uint8), np.array([real], np.uint8)


class PhotoThumbs(CachedScenes):
    """Thumbnails of upright photos in a folder; key ``p12`` is the 12th of ``names`` (paths relative to ``root``).
    A key may repeat: the photo is then served that many times (each time turned and changed anew in training).

    Args:
        root: the photo folder.
        names: the photos, relative to ``root``.
        keys: the samples' keys.
        size: thumbnail side.
        cache_dir: cache root (None: compute every time).
    """

    sample_type = ThumbSample

    def __init__(self, root: str, names: list[str], keys: list[str], size: int = 64,
                 cache_dir: str | None = None) -> None:
        self.root, self.names, self.size = root, list(names), size
        super().__init__(keys, f"photos-{size}", {"root": str(root), "names": self.names, "v": 1}, cache_dir=cache_dir)

    def prepare(self, workers: int = 0, progress: bool | None = None) -> None:
        keys = self.keys
        self.keys = list(dict.fromkeys(keys))  # each photo once
        try:
            super().prepare(workers, progress)
        finally:
            self.keys = keys

    def compute(self, key: str) -> ThumbSample:
        rgb = read_image_file(f"{self.root}/{self.names[int(key[1:])]}")
        return ThumbSample(thumb_of(rgb, self.size), *_flags(1, 1))


def sample_keys(render_seed: int, structureless_seed: int, count: int, structureless_every: int) -> list[str]:
    """``count`` keys, every ``structureless_every``-th a structure-free image."""
    keys, r, s = [], render_seed, structureless_seed
    for i in range(count):
        if (i + 1) % structureless_every == 0:
            keys, s = [*keys, f"s{s}"], s + 1
        else:
            keys, r = [*keys, f"r{r}"], r + 1
    return keys


class UprightDataModule(SceneDataModule):
    """Training, validation and test thumbnails: renders and structure-free images on the seed ranges of
    :class:`~ngp_kornia.training.datamodules.RenderedDataModule` and :data:`STRUCTURELESS_SEEDS`, and, given a
    folder of upright photos, its parts (:func:`~ngp_kornia.data.photo_split.split_photos`): ``train`` in the
    training set, ``calibrate`` in the validation set and ``test`` in the test set.

    In the validation and test sets each photo comes four times in a row, before the renders, so that turning the
    k-th sample by ``k mod 4`` quarter turns (as the module does) shows every photo in every turn.

    Args:
        cache_dir: on-disk cache folder (None: no cache).
        train_size, val_size, test_size: render samples per set.
        size: the network's thumbnail side.
        store_size: the side the thumbnails are cached at (None: ``size``); training crops them, then averages
            them down to ``size``.
        structureless_every: every n-th render sample is structure-free.
        photos: a folder of upright photos (None: renders only).
        photo_repeats: how many times each training photo is served per epoch.
        batch_size: samples per batch.
        num_workers: loader worker processes (also used to fill the cache).
        render: :class:`RenderConfig` settings of the scenes.

    Example:
        >>> dm = UprightDataModule(cache_dir=None, train_size=3, val_size=1, test_size=1, structureless_every=3)
        >>> dm.setup("fit"); batch = next(iter(dm.train_dataloader()))
        >>> tuple(batch.thumbs.shape), int(batch.structured.sum()), int(batch.real.sum())
        ((3, 3, 64, 64), 2, 0)
    """

    collate = staticmethod(collate_thumbs)

    def __init__(self, cache_dir: str | None = "cache", train_size: int = 8000, val_size: int = 600,
                 test_size: int = 600, size: int = 64, store_size: int | None = None, structureless_every: int = 6,
                 photos: str | None = None, photo_repeats: int = 4, batch_size: int = 64, num_workers: int = 0,
                 render: dict | None = None) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, JoinedScenes]:
        hp = self.hparams
        store = hp.store_size or hp.size
        if store < hp.size:
            raise ValueError(f"store_size must be at least size ({hp.size}), got {store}")
        starts = {"train": 0, "val": RenderedDataModule.VAL_SEED, "test": RenderedDataModule.TEST_SEED}
        sizes = {"train": hp.train_size, "val": hp.val_size, "test": hp.test_size}
        config = RenderConfig(**(hp.render or {}))
        out = {}
        for name, start in starts.items():
            keys = sample_keys(start, STRUCTURELESS_SEEDS[name], sizes[name], hp.structureless_every)
            parts = [UprightThumbs(keys, store, config, hp.cache_dir)]
            if hp.photos is not None:
                parts.insert(0, self._photos(name, store))
            out[name] = JoinedScenes(parts)
        return out

    def _photos(self, name: str, store: int) -> PhotoThumbs:
        """The photos of one set: the ``train`` part served ``photo_repeats`` times, the held-back parts four times
        in a row (one per turn)."""
        hp = self.hparams
        names = split_photos(hp.photos, {"train": "train", "val": "calibrate", "test": "test"}[name])
        repeats = hp.photo_repeats if name == "train" else 4
        keys = [f"p{i}" for i in range(len(names)) for _ in range(repeats)]
        if name == "train":  # not in a row: the loader shuffles them anyway
            keys = [f"p{i}" for _ in range(repeats) for i in range(len(names))]
        return PhotoThumbs(hp.photos, names, keys, store, hp.cache_dir)
