"""Training data from NYU-VP's real indoor scenes (:class:`ngp_kornia.data.NYUVP`), alone or beside renders: the
scenes as :class:`~ngp_kornia.training.scene_data.Sample` for ZSNet, and as
:class:`~ngp_kornia.training.evidence_data.LineSample` for the line-evidence network.

The scenes have no pixels, only their LSD segments and labelled vanishing points, so only the networks that read
segments learn from them. Labels of the segments come from the labelled vanishing points as those of the renders
come from the true ones (:func:`~ngp_kornia.training.synth.line_labels.direction_classes`): a segment pointing at the
vertical one is vertical, at another one horizontal, and either is structure; the rest is neither, and no structure.
Scenes without a vertical vanishing point (no zenith truth) are left out.

Splits: the set's training scenes (0-999) are cut into training (:data:`TRAIN_RANGE`) and validation
(:data:`VAL_RANGE`, for checkpoints); its validation scenes (1000-1223) are the test set, kept for decisions.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from ngp_kornia.data.nyu import NYUVP, VALIDATION_SCENES, NYUVPSample
from ngp_kornia.nets.line_features import FEATURE_NAMES, segment_features
from ngp_kornia.pipeline.segments import longest_segments, pad_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.training.datamodules import SceneDataModule
from ngp_kornia.training.evidence_data import LABEL_VERSION, LineSample, RenderedLines, collate_lines
from ngp_kornia.training.scene_data import CachedScenes, JoinedScenes, RenderedScenes, Sample
from ngp_kornia.training.synth.line_labels import direction_classes
from ngp_kornia.training.synth.render_config import RenderConfig

__all__ = [
    "NYULines",
    "NYULinesDataModule",
    "NYUScenes",
    "NYUScenesDataModule",
    "TRAIN_RANGE",
    "VAL_RANGE",
    "nyu_line_labels",
    "nyu_rotation",
]

#: scenes trained on, and scenes that pick the checkpoint (both within the set's own training split, 0-999)
TRAIN_RANGE, VAL_RANGE = (0, 900), (900, 1000)


def _kept_segments(sample: NYUVPSample) -> np.ndarray:
    """The scene's segments as the parser's detection keeps them (its default length and count limits)."""
    settings = SegmentSettings()
    return longest_segments(sample.segments.numpy(), settings.min_length, settings.max_segments).astype(np.float32)


def nyu_rotation(sample: NYUVPSample) -> torch.Tensor:
    """A world-to-camera rotation with the scene's true vertical (column 1 = down) and, where one is labelled, a
    horizontal vanishing point's direction as column 0 (re-orthogonalised); else any horizontal direction.

    Raises:
        ValueError: the scene has no vertical vanishing point.
    """
    if sample.up is None:
        raise ValueError(f"{sample.name} has no vertical vanishing point")
    down = -sample.up
    others = [i for i in range(len(sample.vps)) if i != sample.vertical]
    axes = [torch.linalg.solve(sample.K, sample.vps[i]) for i in others] + [torch.tensor([1.0, 0.0, 0.0]).double()]
    for h in axes:
        h = h - (h @ down) * down
        if float(h.norm()) > 1e-6:
            h = h / h.norm()
            return torch.stack([h, down, torch.linalg.cross(h, down)], -1)
    h = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # down lies along x: z is horizontal
    return torch.stack([h, down, torch.linalg.cross(h, down)], -1)


def nyu_line_labels(segments: np.ndarray, sample: NYUVPSample) -> tuple[np.ndarray, np.ndarray]:
    """Structure targets (N,) float32 and direction classes (N,) int64 of segments from a scene's labelled
    vanishing points (see the module's docstring)."""
    if sample.vertical is None:
        raise ValueError(f"{sample.name} has no vertical vanishing point")
    horizontal = torch.cat([sample.vps[:sample.vertical], sample.vps[sample.vertical + 1:]])
    direction = direction_classes(torch.from_numpy(segments).double(), sample.vps[sample.vertical], horizontal)
    return (direction < 2).numpy().astype(np.float32), direction.numpy()


class _NYUCached(CachedScenes):
    """Base of the NYU-VP datasets: the scenes with a vertical vanishing point among ``scenes`` (those whose files
    are there: a part of the set can be read)."""

    def __init__(self, root: str | Path, scenes: Sequence[int], tag: str, spec: dict, cache_dir) -> None:
        wanted = set(scenes)
        self.reader = NYUVP(root, [s for s in NYUVP(root).scenes if s in wanted])
        keys = [s.index for s in self.reader if s.up is not None]
        super().__init__(keys, tag, {"root": str(Path(root).resolve()), **spec}, cache_dir=cache_dir)


class NYUScenes(_NYUCached):
    """NYU-VP scenes as :class:`~ngp_kornia.training.scene_data.Sample` (segments, K, R, zenith, horizon).

    Args:
        root: the NYU-VP folder.
        scenes: scene numbers.
        cache_dir: cache root (None: read the files every time; they are small).
    """

    def __init__(self, root: str | Path, scenes: Sequence[int], cache_dir: str | Path | None = None) -> None:
        super().__init__(root, scenes, "nyu-scenes", {}, cache_dir)

    def compute(self, key: int) -> Sample:
        s = self.reader.scene(key)
        as_np = [np.asarray(v, dtype=np.float64) for v in (s.K, nyu_rotation(s), s.zenith, s.horizon)]
        return Sample(_kept_segments(s), *as_np, image_size=np.array([s.height, s.width]))


class NYULines(_NYUCached):
    """NYU-VP scenes as :class:`~ngp_kornia.training.evidence_data.LineSample` (segments, features, labels).

    Args:
        root: the NYU-VP folder.
        scenes: scene numbers.
        cache_dir: cache root (None: compute every time).
    """

    sample_type = LineSample

    def __init__(self, root: str | Path, scenes: Sequence[int], cache_dir: str | Path | None = None) -> None:
        spec = {"labels": LABEL_VERSION, "features": list(FEATURE_NAMES)}
        super().__init__(root, scenes, "nyu-lines", spec, cache_dir)

    def compute(self, key: int) -> LineSample:
        s = self.reader.scene(key)
        segments = _kept_segments(s)
        padded, mask = pad_segments([segments])
        stand_in = torch.zeros((), dtype=torch.float32).expand(1, 3, s.height, s.width)  # only its size is read
        with torch.no_grad():
            features = segment_features(stand_in, padded, mask)[0].numpy().astype(np.float32)
        structure, direction = nyu_line_labels(segments, s)
        return LineSample(segments, features, structure, direction, np.array([s.height, s.width]))


def _splits(root: str, kind: type, cache_dir) -> dict[str, CachedScenes]:
    ranges = {"train": range(*TRAIN_RANGE), "val": range(*VAL_RANGE), "test": VALIDATION_SCENES}
    return {name: kind(root, scenes, cache_dir) for name, scenes in ranges.items()}


class NYUScenesDataModule(SceneDataModule):
    """NYU-VP's scenes for ZSNet, with renders beside them in training if asked.

    Training: scenes 0-899 (and ``renders`` rendered scenes, the seeds of
    :class:`~ngp_kornia.training.datamodules.RenderedDataModule`'s training set); validation: scenes 900-999;
    test: the set's validation split, 1000-1223.

    Args:
        root: the NYU-VP folder.
        renders: rendered training scenes joined to the real ones (0: real scenes only).
        cache_dir: cache folder.
        batch_size: scenes per batch.
        num_workers: loader worker processes (also used to fill the cache).
    """

    def __init__(self, root: str, renders: int = 0, cache_dir: str | None = "cache", batch_size: int = 16,
                 num_workers: int = 0) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        out = _splits(hp.root, NYUScenes, hp.cache_dir)
        if hp.renders > 0:
            out["train"] = JoinedScenes([out["train"], RenderedScenes(range(hp.renders), cache_dir=hp.cache_dir)])
        return out


class NYULinesDataModule(SceneDataModule):
    """NYU-VP's scenes for the line-evidence network, with labelled renders beside them in training if asked (the
    splits of :class:`NYUScenesDataModule`).

    Args:
        root: the NYU-VP folder.
        renders: rendered training scenes joined to the real ones (0: real scenes only).
        cache_dir: cache folder.
        batch_size: scenes per batch.
        num_workers: loader worker processes (also used to fill the cache).
        render: :class:`RenderConfig` settings of the renders.
    """

    collate = staticmethod(collate_lines)

    def __init__(self, root: str, renders: int = 0, cache_dir: str | None = "cache", batch_size: int = 16,
                 num_workers: int = 0, render: dict | None = None) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        out = _splits(hp.root, NYULines, hp.cache_dir)
        if hp.renders > 0:
            config = RenderConfig(**(hp.render or {}))
            rendered = RenderedLines(range(hp.renders), (640, 480), config, hp.cache_dir)
            out["train"] = JoinedScenes([out["train"], rendered])
        return out
