"""Lightning DataModules of the training samples (:mod:`ngp_kornia.training.scene_data`): rendered scenes,
panorama crops and manifest photos, split into disjoint seed ranges."""

from __future__ import annotations

import lightning as L
from torch.utils.data import DataLoader

from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.manifest import CSVManifest
from ngp_kornia.training.scene_data import (
    CachedScenes,
    JoinedScenes,
    ManifestScenes,
    PanoramaCrops,
    RenderedScenes,
    collate_scenes,
)
from ngp_kornia.training.synth.render_config import RenderConfig

__all__ = [
    "ManifestDataModule",
    "PhotosAndRendersDataModule",
    "PanoramaDataModule",
    "RenderedDataModule",
    "SceneDataModule",
]


class SceneDataModule(L.LightningDataModule):
    """Base of the DataModules: train / val / test :class:`CachedScenes` batched into :class:`SceneBatch`.

    ``prepare_data`` fills the caches (in ``num_workers`` processes, with a progress bar on a terminal). Under a
    Trainer with ``fast_dev_run=n`` every set is cut to its first ``n * batch_size`` samples, so a smoke test makes
    only what it reads. Loaders shuffle only the training set, so validation and test batches are the same on every
    run.
    """

    #: how the loaders batch the samples
    collate = staticmethod(collate_scenes)

    def __init__(self, batch_size: int = 16, num_workers: int = 0) -> None:
        super().__init__()
        self.batch_size, self.num_workers = batch_size, num_workers
        self.datasets: dict[str, CachedScenes] = {}

    def make_datasets(self) -> dict[str, CachedScenes]:
        """The ``train``, ``val`` and ``test`` datasets."""
        raise NotImplementedError

    def _running_trainer(self) -> L.Trainer | None:
        """The Trainer calling this DataModule now (None outside a Trainer call, or after one has finished)."""
        trainer = self.trainer
        if trainer is None or getattr(trainer.state.status, "value", None) != "running":
            return None
        return trainer

    def _sized_datasets(self) -> dict[str, CachedScenes]:
        """:meth:`make_datasets`, each cut to what a ``fast_dev_run`` reads when the Trainer runs one."""
        datasets = self.make_datasets()
        trainer = self._running_trainer()
        if trainer is not None and trainer.fast_dev_run:
            keep = int(trainer.fast_dev_run) * self.batch_size  # True counts as 1 batch
            for dataset in datasets.values():
                dataset.keys = dataset.keys[:keep]
        return datasets

    def prepare_data(self) -> None:
        datasets = self._sized_datasets()
        trainer = self._running_trainer()
        fn = None if trainer is None else getattr(trainer.state.fn, "value", None)
        needed = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(fn, tuple(datasets))
        for name in needed:  # the sets this Trainer call reads (all of them outside a Trainer)
            datasets[name].prepare(self.num_workers)

    def setup(self, stage: str | None = None) -> None:
        self.datasets = self._sized_datasets()

    def _loader(self, name: str, shuffle: bool) -> DataLoader:
        return DataLoader(
            self.datasets[name],
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            collate_fn=self.collate,
            persistent_workers=self.num_workers > 0,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)


class RenderedDataModule(SceneDataModule):
    """Rendered training, validation and test scenes on disjoint, fixed seed ranges.

    Args:
        cache_dir: on-disk cache folder (None: no cache).
        train_size: number of training scenes (seeds ``0 .. train_size - 1``).
        val_size: validation scenes (seeds from 1,000,000).
        test_size: test scenes (seeds from 2,000,000).
        size: rendered image size ``(W, H)``.
        batch_size: batch size of every loader.
        num_workers: loader worker processes (also used to fill the cache).
        input_size: also load images resized to ``(w, h)``, for FSNet.
        max_segments: longest segments kept per image.
        hard_size: extra training scenes rendered with ``hard_config`` (seeds from 3,000,000), after the others.
        hard_config: :class:`RenderConfig` settings of those scenes, e.g. ``{"stairs": 1.5, "fronto_prob": 0.3}``.

    Example:
        >>> dm = RenderedDataModule(cache_dir=None, train_size=2, val_size=1, test_size=1, size=(160, 120))
        >>> dm.setup("fit"); batch = next(iter(dm.train_dataloader()))
        >>> batch.segments.shape[0], batch.K.shape
        (2, torch.Size([2, 3, 3]))
    """

    VAL_SEED, TEST_SEED, HARD_SEED = 1_000_000, 2_000_000, 3_000_000

    def __init__(
        self,
        cache_dir: str | None = "cache",
        train_size: int = 10_000,
        val_size: int = 500,
        test_size: int = 500,
        size: tuple[int, int] = (640, 480),
        batch_size: int = 16,
        num_workers: int = 0,
        input_size: tuple[int, int] | None = None,
        max_segments: int = 512,
        hard_size: int = 0,
        hard_config: dict | None = None,
    ) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        ranges = {
            "train": (0, hp.train_size),
            "val": (self.VAL_SEED, hp.val_size),
            "test": (self.TEST_SEED, hp.test_size),
        }
        kwargs = {"cache_dir": hp.cache_dir, "max_segments": hp.max_segments, "input_size": hp.input_size}
        out = {k: RenderedScenes(range(a, a + n), tuple(hp.size), **kwargs) for k, (a, n) in ranges.items()}
        if hp.hard_size > 0:
            hard = RenderedScenes(range(self.HARD_SEED, self.HARD_SEED + hp.hard_size), tuple(hp.size),
                                  RenderConfig(**(hp.hard_config or {})), **kwargs)
            out["train"] = JoinedScenes([out["train"], hard])
        return out


class PanoramaDataModule(SceneDataModule):
    """Perspective crops of a folder of equirectangular panoramas; the panoramas (not the crops) are split into
    train / val / test, so no panorama is seen in two sets.

    Args:
        panorama_dir: folder of panorama images (2:1 equirectangular).
        crops: crops per panorama.
        val_fraction: share of the panoramas for validation.
        test_fraction: share of the panoramas for testing.
        size: crop size ``(W, H)``.
        cache_dir: on-disk cache folder.
        batch_size: batch size.
        num_workers: loader worker processes.
        input_size: also load the crops resized to ``(w, h)``, for FSNet.
        seed: seed of the crop parameters.
    """

    def __init__(
        self,
        panorama_dir: str,
        crops: int = 10,
        val_fraction: float = 0.1,
        test_fraction: float = 0.1,
        size: tuple[int, int] = (640, 480),
        cache_dir: str | None = "cache",
        batch_size: int = 16,
        num_workers: int = 0,
        input_size: tuple[int, int] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        files = ImageFolder(hp.panorama_dir).paths
        if len(files) < 3:
            raise ValueError(f"{hp.panorama_dir}: found {len(files)} panorama images, need at least 3 to split")
        n_val = max(1, round(len(files) * hp.val_fraction))
        n_test = max(1, round(len(files) * hp.test_fraction))
        splits = {"val": files[:n_val], "test": files[n_val : n_val + n_test], "train": files[n_val + n_test :]}
        kwargs = {"cache_dir": hp.cache_dir, "input_size": hp.input_size}
        return {k: PanoramaCrops(v, hp.crops, tuple(hp.size), hp.seed, **kwargs) for k, v in splits.items()}


class ManifestDataModule(SceneDataModule):
    """Labelled photos from CSV manifests, one per split (rows without focal length or up direction are skipped).

    Args:
        train: training manifest (CSV path).
        val: validation manifest.
        test: test manifest (optional; defaults to the validation one).
        cache_dir: on-disk cache folder.
        batch_size: batch size; photos of different sizes cannot share a batch, so use 1 for mixed sizes.
        num_workers: loader worker processes.
        input_size: also load images resized to ``(w, h)``, for FSNet.
    """

    def __init__(
        self,
        train: str,
        val: str,
        test: str | None = None,
        cache_dir: str | None = "cache",
        batch_size: int = 1,
        num_workers: int = 0,
        input_size: tuple[int, int] | None = None,
    ) -> None:
        super().__init__(batch_size, num_workers)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        kwargs = {"cache_dir": hp.cache_dir, "input_size": hp.input_size}
        paths = {"train": hp.train, "val": hp.val, "test": hp.test or hp.val}
        return {k: ManifestScenes(CSVManifest(v), **kwargs) for k, v in paths.items()}


class PhotosAndRendersDataModule(RenderedDataModule):
    """Rendered scenes mixed with labelled photos (e.g. the labels :mod:`ngp_kornia.training.pseudo_labels` wrote
    for real photos), every photo cut and resized to the renders' size so that both share a batch.

    Training draws from the renders and the ``train_labels`` photos together; validation and test read the
    ``val_labels`` photos, then ``val_size`` validation renders (held-back photos with sure labels are few).

    Args:
        train_labels: CSV manifest of the training photos.
        val_labels: CSV manifest of the held-back photos (validation and test).
        photo_root: folder the manifests' image paths are relative to (None: each CSV file's folder).
        photo_repeat: how many times each training photo is listed beside the renders.
        val_size: validation renders after the held-back photos (0: the photos alone).
        **kwargs: see :class:`RenderedDataModule`.
    """

    def __init__(
        self,
        train_labels: str,
        val_labels: str,
        photo_root: str | None = None,
        photo_repeat: int = 1,
        val_size: int = 0,
        cache_dir: str | None = "cache",
        train_size: int = 10_000,
        size: tuple[int, int] = (640, 480),
        batch_size: int = 16,
        num_workers: int = 0,
        input_size: tuple[int, int] | None = None,
        max_segments: int = 512,
    ) -> None:
        super().__init__(cache_dir, train_size, val_size, 0, size, batch_size, num_workers, input_size, max_segments)
        self.save_hyperparameters()

    def make_datasets(self) -> dict[str, CachedScenes]:
        hp = self.hparams
        kwargs = {"cache_dir": hp.cache_dir, "max_segments": hp.max_segments, "input_size": hp.input_size}
        renders = RenderedScenes(range(hp.train_size), tuple(hp.size), **kwargs)

        def photos(path: str, repeat: int = 1) -> ManifestScenes:
            return ManifestScenes(CSVManifest(path, hp.photo_root), tuple(hp.size), repeat, **kwargs)

        held = photos(hp.val_labels)
        if hp.val_size > 0:
            seeds = range(self.VAL_SEED, self.VAL_SEED + hp.val_size)
            held = JoinedScenes([held, RenderedScenes(seeds, tuple(hp.size), **kwargs)])
        return {"train": JoinedScenes([renders, photos(hp.train_labels, hp.photo_repeat)]), "val": held, "test": held}
