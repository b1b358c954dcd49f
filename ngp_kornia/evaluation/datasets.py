"""Labelled images for evaluation: the York Urban DB (with either ground-truth horizon), CSV manifests and folders
written by ``ngp render``, all read into one type, :class:`LabelledImage`, so every method and metric is shared.

Scenes given as segments without pixels (NYU-VP, :func:`load_nyu`) carry their segments instead of an image file; the
methods run the parser on them directly.

Two ground-truth horizons exist for York Urban (see :func:`load_yud`): ``"calibrated"``, the dataset's own camera
(``K^-T up`` with the true, off-centre principal point and the orthogonalised vertical), and ``"published"``, the
line through the two raw horizontal vanishing points that the literature's horizon benchmarks draw
(:func:`ngp_kornia.data.yud.published_horizon`). Report both.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.data.manifest import CSVManifest
from ngp_kornia.data.nyu import NYUVP, VALIDATION_SCENES
from ngp_kornia.data.yud import YorkUrbanDB, published_horizon
from ngp_kornia.geometry.camera import horizon_from_zenith, pitch_roll_from_up, zenith_from_up
from ngp_kornia.metrics import horizon_error
from ngp_kornia.pipeline.result import lens_from_dict

__all__ = ["YUD_HORIZONS", "LabelledImage", "load_manifest", "load_nyu", "load_renders", "load_yud"]

#: the ground-truth horizons :func:`load_yud` offers
YUD_HORIZONS = ("calibrated", "published")


@dataclass(frozen=True)
class LabelledImage:
    """One image and its ground truth, in this package's conventions (float64 tensors, degrees, pixels).

    Every field after ``width`` is ``None`` where the source does not give it (a CSV manifest with a horizon only,
    for example); the metrics that need it are then skipped for that image.

    Attributes:
        name: a name unique within its dataset (York Urban folder, manifest path, render file stem, NYU-VP scene).
        image_path: the image file; ``None`` for a scene given as segments.
        height: image height in pixels.
        width: image width in pixels.
        horizon: (3,) horizon line ``(a, b, c)`` in pixels.
        K: (3, 3) intrinsics.
        up: (3,) unit up vector in camera coordinates (``-R[:, 1]``).
        pitch: degrees, > 0 looking up.
        roll: degrees.
        fov_v: vertical field of view, degrees.
        kind: the scene kind of a rendered image (street / indoor / atlanta); ``None`` for photos.
        lens: the radial distortion a rendered image was drawn with (the division model's coefficient of
            :mod:`ngp_kornia.geometry.lens`; 0 for a pinhole render); ``None`` for photos.
        segments: (N, 2, 2) the scene's line segments in pixels, for a scene given without pixels; ``None`` else.
    """

    name: str
    image_path: Path | None
    height: int
    width: int
    horizon: Tensor | None = None
    K: Tensor | None = None
    up: Tensor | None = None
    pitch: float | None = None
    roll: float | None = None
    fov_v: float | None = None
    kind: str | None = None
    lens: float | None = None
    segments: Tensor | None = None


def load_yud(
    root: str | Path, split: str = "all", horizon: str = "calibrated", ground_truth: str = "orthogonal"
) -> list[LabelledImage]:
    """The images of a York Urban DB folder (official layout) with one of its two ground-truth horizons.

    Args:
        root: the database folder (see :class:`ngp_kornia.data.YorkUrbanDB`).
        split: ``"all"``, ``"train"`` or ``"test"`` (the ECCV 2008 split; absent folders are skipped).
        horizon: ``"calibrated"`` (``K^-T up``, the dataset's own camera) or ``"published"`` (the line through the
            two raw horizontal vanishing points, :func:`ngp_kornia.data.yud.published_horizon`).
        ground_truth: where up, pitch and roll (and the calibrated horizon) come from: ``"orthogonal"``
            (``vp_orthogonal``) or ``"raw"`` (the vertical of ``vp``).

    Returns:
        one :class:`LabelledImage` per image, in the database's order; K, up, pitch, roll and fov_v are the same
        for both horizons.

    Raises:
        FileNotFoundError: ``root`` or a file of the database is missing.
        ValueError: an unknown ``horizon``, ``split`` or ``ground_truth``.
    """
    if horizon not in YUD_HORIZONS:
        raise ValueError(f"horizon must be one of {YUD_HORIZONS}, got {horizon!r}")
    images = []
    for s in YorkUrbanDB(root, split=split, ground_truth=ground_truth):
        line = s.horizon if horizon == "calibrated" else published_horizon(s)
        images.append(LabelledImage(s.name, s.image_path, s.height, s.width, line, s.K, s.up, s.pitch, s.roll, s.fov_v))
    return images


def load_manifest(path: str | Path, root: str | Path | None = None) -> list[LabelledImage]:
    """The images of a CSV manifest (:class:`ngp_kornia.data.CSVManifest`) with whatever ground truth it gives.

    Args:
        path: the CSV file.
        root: folder the image paths are relative to; the CSV file's folder when omitted.

    Returns:
        one :class:`LabelledImage` per row, named by the image path relative to ``root`` where possible.

    Raises:
        FileNotFoundError: the CSV file or listed images are missing.
        ngp_kornia.data.ManifestError: a malformed or contradictory row (the message names the line).
    """
    manifest = CSVManifest(path, root)
    images = []
    for s in manifest.validate():
        try:
            name = str(s.image_path.relative_to(manifest.root))
        except ValueError:
            name = str(s.image_path)
        images.append(
            LabelledImage(name, s.image_path, s.height, s.width, s.horizon, s.K, s.up, s.pitch, s.roll, s.fov_v)
        )
    return images


def load_nyu(root: str | Path, scenes=VALIDATION_SCENES) -> list[LabelledImage]:
    """The scenes of an NYU-VP folder (:class:`ngp_kornia.data.NYUVP`) that have a horizon truth, as segments.

    Args:
        root: the folder holding ``data/``.
        scenes: scene numbers; by default the set's validation split (1000-1223), the one to decide on.

    Returns:
        one :class:`LabelledImage` per scene with a vertical vanishing point (the others have no horizon truth and
        are left out), ``image_path`` None and ``segments`` the scene's LSD segments.
    """
    images = []
    for s in NYUVP(root, scenes):
        if s.up is None:
            continue
        images.append(LabelledImage(s.name, None, s.height, s.width, s.horizon, s.K, s.up, s.pitch, s.roll, s.fov_v,
                                    segments=s.segments))
    return images


def _f64(x: object) -> Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float64))


def _render_record(root: Path, rec: dict) -> LabelledImage:
    K, R = _f64(rec["K"]), _f64(rec["R"])
    height, width = int(rec["height"]), int(rec["width"])
    up = -R[:, 1]
    horizon = _f64(rec["horizon"])
    again = horizon_from_zenith(K[None], zenith_from_up(K[None], up[None]))
    pitch, roll = pitch_roll_from_up(up[None])
    lens = lens_from_dict(rec)  # 0 for a render without distortion
    if (
        float(horizon_error(again, horizon[None], height, width)[0]) > 1e-6
        or abs(float(pitch[0]) - rec["pitch"]) > 1e-6
        or abs(float(roll[0]) - rec["roll"]) > 1e-6
    ):
        raise ValueError(f"{root / rec['image']}: stored horizon / pitch / roll disagree with K and R")
    return LabelledImage(
        name=Path(rec["image"]).stem,
        image_path=root / rec["image"],
        height=height,
        width=width,
        horizon=horizon,
        K=K,
        up=up,
        pitch=float(rec["pitch"]),
        roll=float(rec["roll"]),
        fov_v=float(rec["fov_v"]),
        kind=rec.get("kind"),
        lens=0.0 if lens is None else float(lens),
    )


def load_renders(root: str | Path) -> list[LabelledImage]:
    """The images of a folder written by ``ngp render`` (``ground_truth.json`` beside the images).

    The stored horizon, pitch and roll are checked against the ones recomputed from K and R (they must agree, they
    come from the same functions); a mismatch is an error, not a silent re-definition of the ground truth.

    Args:
        root: the folder.

    Returns:
        one :class:`LabelledImage` per image (up = ``-R[:, 1]``, ``kind`` = the scene kind), in the file's order.

    Raises:
        FileNotFoundError: no ``ground_truth.json`` in ``root``.
        ValueError: a record whose stored horizon, pitch or roll disagree with its K and R.
    """
    root = Path(root)
    gt_path = root / "ground_truth.json"
    if not gt_path.is_file():
        raise FileNotFoundError(f"not a render folder (no ground_truth.json): {root}; write one with `ngp render`")
    return [_render_record(root, rec) for rec in json.loads(gt_path.read_text())]
