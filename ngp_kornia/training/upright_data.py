"""Training data of the orientation and structure check (:class:`~ngp_kornia.nets.upright.UprightNet`): thumbnails
of renders (upright; the module turns them) and of structure-free images, cached on disk like the other training
sets (:class:`~ngp_kornia.training.scene_data.CachedScenes`).

Renders come in three shapes (landscape 4:3, portrait 3:4, square) so that a photo's shape says nothing about how
it is turned. Every ``structureless_every``-th sample is a structure-free image
(:func:`~ngp_kornia.training.synth.structureless.structureless_image`) instead of a render.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.nets.upright import thumbnail
from ngp_kornia.training.datamodules import RenderedDataModule, SceneDataModule
from ngp_kornia.training.scene_data import CachedScenes
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig, config_spec
from ngp_kornia.training.synth.structureless import structureless_image

__all__ = ["STRUCTURELESS_SEEDS", "ThumbBatch", "ThumbSample", "UprightDataModule", "UprightThumbs", "collate_thumbs"]

#: first seeds of the structure-free images of the training and validation sets (the test images of
#: ``benchmarks/out_of_world.py`` draw from 5,000,000)
STRUCTURELESS_SEEDS = {"train": 4_000_000, "val": 4_500_000, "test": 4_700_000}
#: rendered shapes ``(W, H)``, drawn by seed
SHAPES = ((640, 480), (640, 480), (640, 480), (480, 640), (480, 640), (512, 512))


@dataclass
class ThumbSample:
    """One upright thumbnail (3, S, S) uint8 and whether it shows structure (1) or not (0)."""

    thumb: np.ndarray
    structured: np.ndarray


@dataclass
class ThumbBatch:
    """Thumbnails (B, 3, S, S) float in [0, 1] and (B,) bool structure flags."""

    thumbs: Tensor
    structured: Tensor

    def __len__(self) -> int:
        return len(self.thumbs)


def collate_thumbs(samples: list[ThumbSample]) -> ThumbBatch:
    thumbs = torch.from_numpy(np.stack([s.thumb for s in samples])).float() / 255.0
    return ThumbBatch(thumbs, torch.from_numpy(np.stack([s.structured for s in samples])).bool().reshape(-1))


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
        spec = {"size": size, "cfg": config_spec(self.config), "shapes": SHAPES, "v": 1}
        super().__init__(keys, f"upright-{size}", spec, cache_dir=cache_dir)

    def compute(self, key: str) -> ThumbSample:
        seed = int(key[1:])
        if key[0] == "s":
            shape = SHAPES[seed % len(SHAPES)]
            return ThumbSample(thumb_of(structureless_image(seed, shape), self.size), np.array([0], np.uint8))
        image = render_scene(seed, SHAPES[seed % len(SHAPES)], self.config).image
        return ThumbSample(thumb_of(image, self.size), np.array([1], np.uint8))


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
    """Training, validation and test thumbnails on the seed ranges of
    :class:`~ngp_kornia.training.datamodules.RenderedDataModule` (renders) and :data:`STRUCTURELESS_SEEDS`.

    Args:
        cache_dir: on-disk cache folder (None: no cache).
        train_size, val_size, test_size: samples per set.
        size: thumbnail side (the network's ``size``).
        structureless_every: every n-th sample is structure-free.
        batch_size: samples per batch.
        num_workers: loader worker processes (also used to fill the cache).
        render: :class:`RenderConfig` settings of the scenes.

    Example:
        >>> dm = UprightDataModule(cache_dir=None, train_size=3, val_size=1, test_size=1, structureless_every=3)
        >>> dm.setup("fit"); batch = next(iter(dm.train_dataloader()))
        >>> tuple(batch.thumbs.shape), int(batch.structured.sum())
        ((3, 3, 64, 64), 2)
    """

    collate = staticmethod(collate_thumbs)

    def __init__(self, cache_dir: str | None = "cache", train_size: int = 8000, val_size: int = 600,
                 test_size: int = 600, size: int = 64, structureless_every: int = 6, batch_size: int = 64,
                 num_workers: int = 0, render: dict | None = None) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, UprightThumbs]:
        hp = self.hparams
        starts = {"train": 0, "val": RenderedDataModule.VAL_SEED, "test": RenderedDataModule.TEST_SEED}
        sizes = {"train": hp.train_size, "val": hp.val_size, "test": hp.test_size}
        config = RenderConfig(**(hp.render or {}))
        return {
            k: UprightThumbs(sample_keys(starts[k], STRUCTURELESS_SEEDS[k], sizes[k], hp.structureless_every),
                             hp.size, config, hp.cache_dir)
            for k in starts
        }  # fmt: skip
