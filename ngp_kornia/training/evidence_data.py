"""Training data of the line-evidence network: rendered scenes reduced to their detected segments, the segments'
features and their labels, cached on disk like the other training sets
(:class:`~ngp_kornia.training.datamodules.CachedScenes`).

Each scene is rendered with its object map, its segments detected as the parser detects them (the default
:class:`~ngp_kornia.pipeline.settings.SegmentSettings`), their features computed by
:func:`~ngp_kornia.nets.line_features.segment_features` (fixed, so they are cached with the sample and training
reads them instead of the image) and labelled by :func:`ngp_kornia.training.synth.line_labels.line_targets`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.nets.line_features import FEATURE_NAMES, segment_features
from ngp_kornia.pipeline.segments import detect_segments, line_workers, pad_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.training.datamodules import RenderedDataModule, SceneDataModule
from ngp_kornia.training.scene_data import CachedScenes
from ngp_kornia.training.synth.line_labels import frame_vanishing_points, line_targets
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig, config_spec

__all__ = ["LineBatch", "LineSample", "LineEvidenceDataModule", "RenderedLines", "collate_lines", "label_render"]

#: changes whenever the features or the labels change, so that old caches are not read
LABEL_VERSION = 2


@dataclass
class LineSample:
    """One render's segments with their features and labels (numpy)."""

    segments: np.ndarray
    features: np.ndarray
    structure: np.ndarray
    direction: np.ndarray
    image_size: np.ndarray


@dataclass
class LineBatch:
    """A batch of :class:`LineSample`, padded.

    Attributes:
        segments: (B, N, 2, 2) pixels.
        mask: (B, N) bool.
        features: (B, N, F) segment features.
        structure: (B, N) structure targets in [0, 1] (the share of the segment on a structural outline).
        direction: (B, N) direction classes (0 vertical, 1 horizontal, 2 neither).
        image_size: (B, 2) ``(height, width)``.
    """

    segments: Tensor
    mask: Tensor
    features: Tensor
    structure: Tensor
    direction: Tensor
    image_size: Tensor

    def __len__(self) -> int:
        return self.segments.shape[0]


def label_render(scene, settings: SegmentSettings | None = None) -> LineSample:
    """Detect, describe and label the segments of a render made with ``objects=True``.

    Args:
        scene: a :class:`~ngp_kornia.training.synth.render.RenderedScene` with its object map.
        settings: the line detection's settings (the defaults when None).

    Returns:
        The sample, segments longest first.
    """
    if scene.objects is None:
        raise ValueError("the render has no object map: render it with render_scene(..., objects=True)")
    with line_workers(1):  # LSD's strips one after the other on this thread: the same segments, one core
        segments, mask = detect_segments(scene.image, settings)
    image = torch.from_numpy(scene.image).permute(2, 0, 1)[None].float() / 255.0
    with torch.no_grad():
        features = segment_features(image, segments, mask)[0]
    seg = segments[0]
    structure, direction = line_targets(seg.numpy(), scene.objects, *frame_vanishing_points(scene.K, scene.R,
                                                                                              scene.frames))
    return LineSample(
        segments=seg.numpy().astype(np.float32),
        features=features.numpy().astype(np.float32),
        structure=structure.astype(np.float32),
        direction=direction,
        image_size=np.array(scene.image.shape[:2]),
    )


class RenderedLines(CachedScenes):
    """Rendered scenes as :class:`LineSample`, one per seed.

    Args:
        seeds: the scenes' seeds.
        size: rendered image size ``(W, H)``.
        config: renderer settings.
        cache_dir: cache root (None: compute every time).
    """

    sample_type = LineSample

    def __init__(self, seeds: Sequence[int], size: tuple[int, int] = (640, 480), config: RenderConfig | None = None,
                 cache_dir: str | None = None) -> None:
        self.size, self.config = tuple(size), config or RenderConfig()
        spec = {"size": self.size, "cfg": config_spec(self.config), "labels": LABEL_VERSION,
                "features": list(FEATURE_NAMES)}
        super().__init__(seeds, f"lines-{self.size[0]}x{self.size[1]}", spec, cache_dir=cache_dir)

    def compute(self, key: int) -> LineSample:
        return label_render(render_scene(key, self.size, self.config, objects=True))


def collate_lines(samples: list[LineSample]) -> LineBatch:
    """Stack samples into a :class:`LineBatch`, padding every per-segment array."""
    segments, mask = pad_segments([torch.from_numpy(s.segments) for s in samples])
    n = segments.shape[1]

    def pad(name: str, fill) -> Tensor:
        rows = []
        for s in samples:
            a = torch.from_numpy(np.asarray(getattr(s, name)))
            rows.append(torch.cat([a, a.new_full((n - len(a), *a.shape[1:]), fill)]))
        return torch.stack(rows)

    return LineBatch(
        segments=segments,
        mask=mask,
        features=pad("features", 0.0).float(),
        structure=pad("structure", 0.0).float(),
        direction=pad("direction", 2).long(),
        image_size=torch.from_numpy(np.stack([s.image_size for s in samples])).long(),
    )


class LineEvidenceDataModule(SceneDataModule):
    """Rendered training, validation and test scenes for the line-evidence network, on the seed ranges of
    :class:`~ngp_kornia.training.datamodules.RenderedDataModule` (disjoint, fixed).

    Args:
        cache_dir: on-disk cache folder (None: no cache).
        train_size: training scenes (seeds ``0 .. train_size - 1``).
        val_size: validation scenes (seeds from 1,000,000).
        test_size: test scenes (seeds from 2,000,000).
        size: rendered image size ``(W, H)``.
        batch_size: scenes per batch.
        num_workers: loader worker processes (also used to fill the cache).
        render: :class:`RenderConfig` settings of the scenes, e.g. ``{"clutter": 2.0}``.

    Example:
        >>> dm = LineEvidenceDataModule(cache_dir=None, train_size=2, val_size=1, test_size=1, size=(160, 120))
        >>> dm.setup("fit"); batch = next(iter(dm.train_dataloader()))
        >>> batch.features.shape[0], batch.features.shape[2] == len(FEATURE_NAMES)
        (2, True)
    """

    collate = staticmethod(collate_lines)

    def __init__(self, cache_dir: str | None = "cache", train_size: int = 8000, val_size: int = 400,
                 test_size: int = 400, size: tuple[int, int] = (640, 480), batch_size: int = 16,
                 num_workers: int = 0, render: dict | None = None) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, RenderedLines]:
        hp = self.hparams
        ranges = {"train": (0, hp.train_size), "val": (RenderedDataModule.VAL_SEED, hp.val_size),
                  "test": (RenderedDataModule.TEST_SEED, hp.test_size)}
        config = RenderConfig(**(hp.render or {}))
        return {k: RenderedLines(range(a, a + n), tuple(hp.size), config, hp.cache_dir) for k, (a, n) in ranges.items()}
