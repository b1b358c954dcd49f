"""Training samples: rendered scenes (or panorama crops, or manifest photos) reduced to LSD segments and exact
ground truth, cached on disk one small ``.npz`` per seed, and their batching.

Each sample depends only on its seed, so a dataset is a list of seeds; train, validation and test sets use
disjoint seed ranges. The first pass renders and detects lines and writes the cache; later epochs (and other
processes) only read those files. :mod:`ngp_kornia.training.datamodules` serves them to Lightning.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import zipfile
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from ngp_kornia.data.manifest import CSVManifest
from ngp_kornia.data.panorama import crop_ground_truth, perspective_crops, sample_crop_params
from ngp_kornia.geometry import horizon_from_zenith, rotation_from_angles, zenith_from_up
from ngp_kornia.io import load_image, read_image_file
from ngp_kornia.pipeline.segments import detect_segments, pad_segments
from ngp_kornia.pipeline.settings import SegmentSettings
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig, config_spec

__all__ = [
    "CACHE_VERSION",
    "CachedScenes",
    "JoinedScenes",
    "ManifestScenes",
    "PanoramaCrops",
    "RenderedScenes",
    "Sample",
    "SceneBatch",
    "collate_scenes",
    "fit_photo",
    "read_cached_sample",
]

CACHE_VERSION = 1


@dataclass
class SceneBatch:
    """A batch of scenes with ground truth; all images of a batch share one size.

    Attributes:
        segments: (B, N, 2, 2) LSD segments in pixels, padded.
        mask: (B, N) bool.
        K: (B, 3, 3) true intrinsics.
        R: (B, 3, 3) true world-to-camera rotation.
        zenith: (B, 3) true zenith VP, homogeneous pixels.
        horizon: (B, 3) true horizon line in pixels.
        image_size: (B, 2) ``(height, width)``.
        images: (B, 3, h, w) float RGB in [0, 1] at the network's input size, or None when not requested.
    """

    segments: Tensor
    mask: Tensor
    K: Tensor
    R: Tensor
    zenith: Tensor
    horizon: Tensor
    image_size: Tensor
    images: Tensor | None = None

    def __len__(self) -> int:
        return self.segments.shape[0]


@dataclass
class Sample:
    segments: np.ndarray
    K: np.ndarray
    R: np.ndarray
    zenith: np.ndarray
    horizon: np.ndarray
    image_size: np.ndarray
    image: np.ndarray | None = None


def _digest(spec: dict) -> str:
    return hashlib.sha1(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()[:12]


def read_cached_sample(path: Path, sample_type: type = Sample):
    """A cached sample (a ``sample_type``, a dataclass of arrays), or None when the file cannot be used (truncated,
    damaged, missing a field without a default, or holding pickled objects, which are never loaded:
    ``allow_pickle=False``); the caller then computes the sample again and rewrites the file."""
    try:
        with np.load(path, allow_pickle=False) as data:
            sample = sample_type(**{f.name: data[f.name] if f.name in data else None for f in fields(sample_type)})
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError):
        return None
    complete = all(getattr(sample, f.name) is not None for f in fields(sample_type) if f.default is MISSING)
    return sample if complete else None


class CachedScenes(Dataset):
    """Base of the scene datasets: ``keys[i]`` -> :class:`Sample` by :meth:`compute`, cached as one ``.npz`` per key
    in a folder named by ``tag`` and a digest of everything that changes the samples.

    Args:
        keys: one hashable key per sample (a seed, an index, ...).
        tag: readable prefix of the cache folder.
        spec: everything that determines the samples besides the key (hashed into the folder name).
        cache_dir: cache root (None: compute every time, write nothing).
        working_size: LSD working resolution (long side). The training renders are 640x480, so 640 detects them as
            the parser's default (up to 1280) does: at their own size; larger training images are detected at 640.
        max_segments: longest segments kept per image.
        input_size: also keep the image resized to ``(w, h)``, the network's input (for FSNet), or None.
    """

    #: the dataclass :meth:`compute` returns and the cache holds
    sample_type: type = Sample

    def __init__(
        self,
        keys: Sequence,
        tag: str,
        spec: dict,
        cache_dir: str | Path | None = None,
        working_size: int = 640,
        max_segments: int = 512,
        input_size: tuple[int, int] | None = None,
    ) -> None:
        self.keys = list(keys)
        self.working_size, self.max_segments = working_size, max_segments
        self.input_size = None if input_size is None else tuple(input_size)
        self.cache = None
        if cache_dir is not None:
            full = {**spec, "v": CACHE_VERSION, "ws": working_size, "max": max_segments, "input": self.input_size}
            self.cache = Path(cache_dir) / f"{tag}-{_digest(full)}"
            self.cache.mkdir(parents=True, exist_ok=True)

    def __len__(self) -> int:
        return len(self.keys)

    def compute(self, key) -> Sample:
        """The sample of one key, uncached."""
        raise NotImplementedError

    def __getitem__(self, index: int) -> Sample:
        key = self.keys[index]
        path = None if self.cache is None else self.cache / f"{key}.npz"
        if path is not None and path.exists():
            cached = read_cached_sample(path, self.sample_type)
            if cached is not None:
                return cached
        sample = self.compute(key)
        if path is not None:
            tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
            np.savez(tmp, **{k: v for k, v in asdict(sample).items() if v is not None})
            tmp.replace(path)  # atomic: readers in other processes never see a partial file
        return sample

    def sample_from_image(self, rgb: np.ndarray, K, R, zenith, horizon) -> Sample:
        """Detect segments on an HxWx3 uint8 RGB image and pack it with its ground truth."""
        # LSD over the whole image in one piece, as the shipped networks were trained (the parser's two strips find
        # 97-99% of the same lines), on one thread in each of the loader's processes
        config = SegmentSettings(working_size=self.working_size, max_segments=self.max_segments, line_strips=1)
        segments = detect_segments(rgb, config)[0][0].numpy()
        image = None
        if self.input_size is not None:
            image = cv2.resize(rgb, self.input_size, interpolation=cv2.INTER_AREA)
        as_np = [np.asarray(torch.as_tensor(v, dtype=torch.float64)) for v in (K, R, zenith, horizon)]
        return Sample(segments, *as_np, image_size=np.array(rgb.shape[:2]), image=image)

    def prepare(self, workers: int = 0, progress: bool | None = None) -> None:
        """Fill the cache for every key (in ``workers`` processes); a no-op for cached keys.

        Args:
            workers: processes to share the work (0 or 1: this one).
            progress: show a progress bar on stderr; None: only when stderr is a terminal.
        """
        if self.cache is None:
            return
        todo = [i for i, k in enumerate(self.keys) if not (self.cache / f"{k}.npz").exists()]
        if not todo:
            return
        from tqdm import tqdm

        show = sys.stderr.isatty() if progress is None else progress
        with tqdm(total=len(todo), desc=f"caching {self.cache.name}", unit="sample", disable=not show) as bar:
            if workers <= 1:
                for i in todo:
                    self[i]
                    bar.update()
                return
            with ProcessPoolExecutor(workers) as pool:
                for _ in pool.map(self.__getitem__, todo, chunksize=4):
                    bar.update()


class RenderedScenes(CachedScenes):
    """Rendered scenes, one per seed (:func:`ngp_kornia.training.synth.render.render_scene`).

    Args:
        seeds: the scenes' seeds.
        size: rendered image size ``(W, H)``.
        config: renderer settings.
        **kwargs: see :class:`CachedScenes`.
    """

    def __init__(
        self, seeds: Sequence[int], size: tuple[int, int] = (640, 480), config: RenderConfig | None = None, **kwargs
    ) -> None:
        self.size, self.config = tuple(size), config or RenderConfig()
        spec = {"size": self.size, "cfg": config_spec(self.config)}
        super().__init__(seeds, f"rendered-{self.size[0]}x{self.size[1]}", spec, **kwargs)

    def compute(self, key: int) -> Sample:
        scene = render_scene(key, self.size, self.config)
        return self.sample_from_image(scene.image, scene.K, scene.R, scene.zenith, scene.horizon)


class JoinedScenes(Dataset):
    """Several scene datasets one after the other (each keeps its own cache).

    Args:
        parts: the datasets.
    """

    def __init__(self, parts: Sequence[CachedScenes]) -> None:
        self.parts = list(parts)

    @property
    def keys(self) -> list:
        return [k for part in self.parts for k in part.keys]

    @keys.setter
    def keys(self, keys: list) -> None:  # a prefix, as fast_dev_run cuts it
        left = len(keys)
        for part in self.parts:
            part.keys, left = part.keys[:left], max(0, left - len(part.keys))

    def __len__(self) -> int:
        return sum(len(part) for part in self.parts)

    def __getitem__(self, index: int) -> Sample:
        for part in self.parts:
            if index < len(part):
                return part[index]
            index -= len(part)
        raise IndexError(index)

    def prepare(self, workers: int = 0, progress: bool | None = None) -> None:
        for part in self.parts:
            part.prepare(workers, progress)


class PanoramaCrops(CachedScenes):
    """Perspective crops of equirectangular panoramas (the paper's data generation), ``crops`` per panorama, with
    camera parameters drawn from the paper's ranges by a seed per crop.

    Args:
        panoramas: panorama image files.
        crops: crops per panorama.
        size: crop size ``(W, H)``.
        seed: base seed of the crop parameters.
        **kwargs: see :class:`CachedScenes`.
    """

    def __init__(
        self, panoramas: Sequence[str | Path], crops: int = 10, size=(640, 480), seed: int = 0, **kwargs
    ) -> None:
        self.panoramas, self.crops, self.size, self.seed = [Path(p) for p in panoramas], crops, tuple(size), seed
        files = [(str(p.resolve()), p.stat().st_mtime_ns) for p in self.panoramas]
        spec = {"files": files, "crops": crops, "size": self.size, "seed": seed}
        super().__init__(range(len(self.panoramas) * crops), "panorama", spec, **kwargs)

    def compute(self, key: int) -> Sample:
        pano = load_image(self.panoramas[key // self.crops])
        params = sample_crop_params(1, torch.Generator().manual_seed(self.seed * 1_000_003 + key), dtype=torch.float64)
        angles = (params["fov_v"], params["pitch"], params["roll"], params["yaw"])
        crop = perspective_crops(pano.double(), *angles, size=self.size)
        rgb = crop[0].permute(1, 2, 0).clamp(0, 1).mul(255).round().byte().numpy()
        gt = crop_ground_truth(**params, size=self.size)
        return self.sample_from_image(rgb, gt["K"][0], gt["R"][0], gt["zenith"][0], gt["horizon"][0])


def fit_photo(rgb: np.ndarray, K: Tensor, size: tuple[int, int]) -> tuple[np.ndarray, Tensor]:
    """The middle of a photo cut to the aspect ratio of ``size = (W, H)`` and resized to it, and its intrinsics: the
    rotation is the photo's, so its horizon and zenith follow from the new ``K``.

    Args:
        rgb: (H0, W0, 3) uint8 image.
        K: (3, 3) its intrinsics.
        size: the output size ``(W, H)``.

    Returns:
        the (H, W, 3) image and its (3, 3) float64 intrinsics (pixel-centre convention).

    Example:
        >>> K = torch.tensor([[500.0, 0, 399.5], [0, 500.0, 299.5], [0, 0, 1]])
        >>> image, K2 = fit_photo(np.zeros((600, 800, 3), np.uint8), K, (400, 300))
        >>> image.shape, K2.diagonal().tolist(), K2[:2, 2].tolist()
        ((300, 400, 3), [250.0, 250.0, 1.0], [199.5, 149.5])
    """
    height, width = rgb.shape[:2]
    scale = min(width / size[0], height / size[1])  # source pixels per output pixel
    crop_w, crop_h = min(width, round(size[0] * scale)), min(height, round(size[1] * scale))
    x0, y0 = (width - crop_w) // 2, (height - crop_h) // 2
    image = cv2.resize(rgb[y0 : y0 + crop_h, x0 : x0 + crop_w], size, interpolation=cv2.INTER_AREA)
    sx, sy = size[0] / crop_w, size[1] / crop_h  # equal up to the rounding of the crop
    K = torch.as_tensor(K, dtype=torch.float64).clone()
    focal = float(K[0, 0]) * (sx + sy) / 2
    cx, cy = (float(K[0, 2]) - x0 + 0.5) * sx - 0.5, (float(K[1, 2]) - y0 + 0.5) * sy - 0.5
    return image, torch.tensor([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]], dtype=torch.float64)


class ManifestScenes(CachedScenes):
    """Labelled photos of a CSV manifest: the rows whose focal length and up direction are known (others are
    skipped, since the networks need both).

    Args:
        manifest: the manifest.
        size: cut and resize every photo to ``(W, H)`` (:func:`fit_photo`), so that photos of any size share a
            batch with each other and with renders of that size; None: as they are.
        repeat: how many times each photo is listed (weighs the photos against other samples in a joined set).
        **kwargs: see :class:`CachedScenes`.
    """

    def __init__(
        self, manifest: CSVManifest, size: tuple[int, int] | None = None, repeat: int = 1, **kwargs
    ) -> None:
        self.manifest, self.size = manifest, None if size is None else tuple(size)
        rows = [i for i, s in enumerate(manifest) if s.K is not None and s.zenith is not None]
        files = [(str(p.resolve()), p.stat().st_mtime_ns) for p in manifest.image_paths]
        spec = {"files": files} if self.size is None else {"files": files, "size": self.size}
        super().__init__(rows * repeat, "manifest", spec, **kwargs)

    def compute(self, key: int) -> Sample:
        row = self.manifest[key]
        R = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (row.pitch, row.roll)))[0]
        rgb = read_image_file(row.image_path)
        if self.size is None:
            return self.sample_from_image(rgb, row.K, R, row.zenith, row.horizon)
        rgb, K = fit_photo(rgb, row.K, self.size)
        zenith = zenith_from_up(K[None], row.up.to(K)[None])
        return self.sample_from_image(rgb, K, R, zenith[0], horizon_from_zenith(K[None], zenith)[0])


def collate_scenes(samples: list[Sample]) -> SceneBatch:
    """Stack samples into a :class:`SceneBatch`, padding segments."""
    segments, mask = pad_segments([s.segments for s in samples])

    def stack(name: str) -> Tensor:
        return torch.from_numpy(np.stack([getattr(s, name) for s in samples]))

    images = None
    if samples[0].image is not None:
        images = stack("image").permute(0, 3, 1, 2).float().div(255.0)
    return SceneBatch(
        segments=segments,
        mask=mask,
        K=stack("K").float(),
        R=stack("R").float(),
        zenith=stack("zenith").float(),
        horizon=stack("horizon").float(),
        image_size=stack("image_size").long(),
        images=images,
    )
