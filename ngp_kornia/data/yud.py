r"""Reader for the York Urban Database (Denis, Elder and Estrada, ECCV 2008) in its official layout.

Expected layout under ``root``::

    cameraParameters.mat                    focal (mm), pixelSize (mm / px), pp (px): one camera for every image
    Manhattan_Image_DB_Names.mat            Manhattan_Image_DB_Names: the folder names (trailing "\" stripped)
    ECCV_TrainingAndTestImageNumbers.mat    trainingSetIndex, testSetIndex: 1-based indices into the names
    <name>/<name>.jpg
    <name>/<name>GroundTruthVP_Orthogonal_CamParams.mat   vp_orthogonal: 3x3, columns = Manhattan directions
    <name>/<name>GroundTruthVP_CamParams.mat              vp: the same before orthogonalisation (optional)
    <name>/<name>LinesAndVP.mat             lines (2n x 2), vp_association (n x 1): hand-labelled segments

Image folders that are absent are skipped, so a partial copy of the database can be read.

The ground-truth directions are given in a camera frame with y **up**; they are converted to this package's
conventions (:mod:`ngp_kornia.geometry.camera`: OpenCV camera frame, world y down) with ``diag(1, -1, 1)``.
Column 2 (1-based) of ``vp_orthogonal`` is the vertical. The rotation ``R`` of a sample has column 0 = the first
horizontal direction, column 1 = the world down direction, column 2 = their cross product, so ``K @ R[:, j]``
is the vanishing point of column ``j + 1`` of the database's ``vp`` (up to sign).

By default the ground truth comes from ``vp_orthogonal``. With ``ground_truth="raw"`` the vertical is taken
exactly from the raw ``vp`` (each column fitted to its own labelled segments; it differs from the orthogonal
one by 0.6 degrees on average and up to 2 degrees) and the horizontal axis is re-orthogonalised against it;
the horizon, pitch and roll then follow the labelled vertical segments alone. Horizon scores differ by about one
AUC point between the two.

Pixel coordinates: ``K`` uses the database's principal point as published. The hand-labelled segments are in
MATLAB's 1-based pixel coordinates (they sit one pixel right of and below the edges found by OpenCV's LSD);
:func:`load_labelled_segments` shifts them by -1 into this package's 0-based pixel-centre convention.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload

import cv2
import numpy as np
import scipy.io
import torch
from torch import Tensor

from ngp_kornia.geometry.camera import (
    fov_from_focal,
    horizon_from_zenith,
    intrinsics_matrix,
    pitch_roll_from_up,
    zenith_from_up,
)

__all__ = ["YUDSample", "YorkUrbanDB", "load_labelled_segments", "published_horizon", "rotation_from_yud_vps"]

CAMERA_FILE = "cameraParameters.mat"
NAMES_FILE = "Manhattan_Image_DB_Names.mat"
SPLIT_FILE = "ECCV_TrainingAndTestImageNumbers.mat"
SPLITS = ("all", "train", "test")
GROUND_TRUTHS = {
    "orthogonal": ("GroundTruthVP_Orthogonal_CamParams", "vp_orthogonal"),
    "raw": ("GroundTruthVP_CamParams", "vp"),
}

_Y_UP_TO_Y_DOWN = torch.diag(torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64))


@dataclass(frozen=True)
class YUDSample:
    """Ground truth of one York Urban image, in this package's conventions (float64 tensors, degrees).

    Attributes:
        name: folder / image name, e.g. ``"P1020177"``.
        split: ``"train"`` or ``"test"`` (ECCV split), ``None`` when the split file is absent.
        image_path: path of the jpg.
        lines_path: path of ``<name>LinesAndVP.mat`` (see :func:`load_labelled_segments`).
        height: image height in pixels.
        width: image width in pixels.
        K: (3, 3) intrinsics.
        R: (3, 3) world-to-camera rotation; column 1 is the world down direction.
        up: (3,) unit up vector in camera coordinates, ``-R[:, 1]``.
        zenith: (3,) homogeneous zenith VP in pixels, ``K @ up``.
        horizon: (3,) horizon line ``(a, b, c)`` in pixels, ``a^2 + b^2 = 1``, ``b >= 0``.
        vps: (3, 3) homogeneous VPs in pixels; row ``j`` is ``K @ R[:, j]``.
        pitch: degrees, > 0 looking up.
        roll: degrees.
        focal: focal length in pixels.
        fov_v: vertical field of view in degrees.
        fov_h: horizontal field of view in degrees.
    """

    name: str
    split: str | None
    image_path: Path
    lines_path: Path
    height: int
    width: int
    K: Tensor
    R: Tensor
    up: Tensor
    zenith: Tensor
    horizon: Tensor
    vps: Tensor
    pitch: float
    roll: float
    focal: float
    fov_v: float
    fov_h: float


def _loadmat(path: Path, keys: Sequence[str]) -> dict[str, Any]:
    if not path.is_file():
        raise FileNotFoundError(f"York Urban DB file not found: {path}")
    try:
        data = scipy.io.loadmat(str(path))
    except Exception as e:  # scipy raises several types for corrupt files
        raise ValueError(f"cannot read {path} as a MATLAB file: {e}") from e
    missing = [k for k in keys if k not in data]
    if missing:
        raise ValueError(f"{path} lacks the variable(s) {missing}; found {sorted(k for k in data if k[0] != '_')}")
    return data


def _cell_strings(cell: np.ndarray) -> list[str]:
    """The strings of a MATLAB cell array of char vectors, trailing backslashes and blanks stripped."""
    out = []
    for item in np.asarray(cell, dtype=object).ravel():
        while isinstance(item, np.ndarray):
            if item.size != 1:
                item = "".join(str(c) for c in item.ravel())
                break
            item = item.ravel()[0]
        out.append(str(item).strip().rstrip("\\/").strip())
    return out


def rotation_from_yud_vps(vp: np.ndarray | Tensor) -> Tensor:
    """World-to-camera rotation in this package's conventions from York Urban ground-truth directions. Ours: the
    database's axes (y up, column 1 vertical) mapped onto this package's frame, which kornia does not know.

    Args:
        vp: (3, 3) ``vp_orthogonal`` (or ``vp``): columns are unit Manhattan directions in a camera frame with
            y up; column 1 (0-based) is the vertical. Signs are arbitrary.

    Returns:
        (3, 3) float64 rotation (det +1): column 0 = the first horizontal direction, column 1 = world down
        (positive image y component), column 2 = column 0 x column 1.

    Example:
        >>> vp = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])  # level camera, y up
        >>> rotation_from_yud_vps(vp)
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]], dtype=torch.float64)
    """
    d = torch.as_tensor(np.asarray(vp, dtype=np.float64)) if not isinstance(vp, Tensor) else vp.double()
    if d.shape != (3, 3):
        raise ValueError(f"vp must be a 3x3 matrix, got shape {tuple(d.shape)}")
    d = _Y_UP_TO_Y_DOWN @ d
    down = d[:, 1] / d[:, 1].norm()
    down = torch.where(down[1] < 0, -down, down)
    h = d[:, 0] - (d[:, 0] @ down) * down  # re-orthogonalise against round-off
    if not bool(h.norm() > 1e-6):
        raise ValueError("vp columns 0 and 1 are parallel: not a Manhattan frame")
    h = h / h.norm()
    return torch.stack([h, down, torch.linalg.cross(h, down)], -1)


def load_labelled_segments(path: str | Path) -> tuple[Tensor, Tensor]:
    """Hand-labelled segments of one image, in 0-based pixel-centre coordinates.

    Args:
        path: a ``<name>LinesAndVP.mat`` file (e.g. :attr:`YUDSample.lines_path`).

    Returns:
        segments (n, 2, 2) float64 ``[[x1, y1], [x2, y2]]`` and vp_index (n,) int64 in 0..2, the column of
        :attr:`YUDSample.R` (and row of :attr:`YUDSample.vps`) the segment points to.
    """
    data = _loadmat(Path(path), ["lines", "vp_association"])
    lines = np.asarray(data["lines"], dtype=np.float64)
    assoc = np.asarray(data["vp_association"]).astype(np.int64).ravel()
    if lines.ndim != 2 or lines.shape[1] != 2 or lines.shape[0] != 2 * assoc.shape[0]:
        raise ValueError(f"{path}: expected lines of shape (2n, 2) with n = {assoc.shape[0]}, got {lines.shape}")
    if assoc.size and (assoc.min() < 1 or assoc.max() > 3):
        raise ValueError(f"{path}: vp_association must lie in 1..3")
    segments = torch.from_numpy(lines.reshape(-1, 2, 2) - 1.0)
    return segments, torch.from_numpy(assoc - 1)


def published_horizon(sample: YUDSample) -> Tensor:
    """The horizon York Urban benchmarks in the literature score against (e.g. Lezama et al., CVPR 2014).

    It is the line through the two *raw* horizontal vanishing points of ``<name>GroundTruthVP_CamParams.mat``
    (columns 0 and 2 of ``vp``, each fitted to its own hand-labelled segments), projected with the true ``K``:
    ``l = (K v_0) x (K v_2)`` (a cross product: kornia's lines are parametric and have no points at infinity).
    :attr:`YUDSample.horizon` is instead ``K^-T up`` with the ground-truth vertical;
    the two lines differ by about 7 px (median) per image.

    Args:
        sample: one image of a :class:`YorkUrbanDB` (its folder must hold the raw ground-truth file).

    Returns:
        (3,) float64 horizon line ``(a, b, c)`` in pixels, ``a^2 + b^2 = 1``, ``b >= 0``.

    Raises:
        FileNotFoundError: the raw ground-truth file is missing.
        ValueError: the two horizontal vanishing points coincide.
    """
    suffix, key = GROUND_TRUTHS["raw"]
    path = sample.image_path.parent / f"{sample.name}{suffix}.mat"
    vp = torch.as_tensor(np.asarray(_loadmat(path, [key])[key], dtype=np.float64))
    if vp.shape != (3, 3):
        raise ValueError(f"{path}: vp must be a 3x3 matrix, got shape {tuple(vp.shape)}")
    points = sample.K.double() @ _Y_UP_TO_Y_DOWN @ vp  # columns: homogeneous VPs in pixels
    line = torch.linalg.cross(points[:, 0], points[:, 2])
    scale = line[:2].norm()
    if not bool(scale > 1e-12 * line.norm()):
        raise ValueError(f"{path}: the horizontal vanishing points coincide; no horizon through them")
    line = line / scale
    return -line if line[1] < 0 else line


class YorkUrbanDB(Sequence[YUDSample]):
    """The York Urban Database as a sequence of :class:`YUDSample`.

    Args:
        root: folder holding the database in its official layout.
        split: ``"all"`` (every listed folder), ``"train"`` or ``"test"`` (the ECCV 2008 split). Folders absent
            from ``root`` are skipped.
        ground_truth: ``"orthogonal"`` (``vp_orthogonal``, the default) or ``"raw"`` (the vertical of ``vp``).

    Raises:
        FileNotFoundError: ``root`` or one of its .mat files (or a present folder's files) is missing.
        ValueError: unknown split or malformed files.

    Usage::

        db = YorkUrbanDB("/path/to/YorkUrbanDB", split="train")
        for s in db:
            s.image_path, s.K, s.R, s.horizon, s.pitch, s.roll

    Example:
        >>> YorkUrbanDB("/no/such/folder")
        Traceback (most recent call last):
        ...
        FileNotFoundError: York Urban DB root not found (or not a folder): /no/such/folder
    """

    def __init__(self, root: str | Path, split: str = "all", ground_truth: str = "orthogonal") -> None:
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        if ground_truth not in GROUND_TRUTHS:
            raise ValueError(f"ground_truth must be one of {tuple(GROUND_TRUTHS)}, got {ground_truth!r}")
        self.ground_truth = ground_truth
        self.root = Path(root)
        self.split = split
        if not self.root.is_dir():
            raise FileNotFoundError(f"York Urban DB root not found (or not a folder): {self.root}")

        cam = _loadmat(self.root / CAMERA_FILE, ["focal", "pixelSize", "pp"])
        focal = float(np.asarray(cam["focal"], dtype=np.float64).ravel()[0])
        pixel_size = float(np.asarray(cam["pixelSize"], dtype=np.float64).ravel()[0])
        pp = np.asarray(cam["pp"], dtype=np.float64).ravel()
        if pixel_size <= 0 or focal <= 0 or pp.size != 2:
            raise ValueError(f"{self.root / CAMERA_FILE}: invalid focal, pixelSize or pp")
        self.focal = focal / pixel_size
        self.K = intrinsics_matrix(torch.tensor([self.focal], dtype=torch.float64), torch.from_numpy(pp))[0]

        names_mat = _loadmat(self.root / NAMES_FILE, ["Manhattan_Image_DB_Names"])
        names = _cell_strings(names_mat["Manhattan_Image_DB_Names"])
        split_of: dict[str, str] = {}
        members: dict[str, list[str]] = {"all": names}
        split_path = self.root / SPLIT_FILE
        if split != "all" or split_path.is_file():
            idx = _loadmat(split_path, ["trainingSetIndex", "testSetIndex"])
            for key, label in (("trainingSetIndex", "train"), ("testSetIndex", "test")):
                order = np.asarray(idx[key]).astype(np.int64).ravel()
                if order.size and (order.min() < 1 or order.max() > len(names)):
                    raise ValueError(f"{split_path}: {key} must lie in 1..{len(names)}")
                members[label] = [names[i - 1] for i in order]
                split_of.update((n, label) for n in members[label])
        selected = members[split]

        self.samples: list[YUDSample] = [self._load(n, split_of.get(n)) for n in selected if (self.root / n).is_dir()]

    def _load(self, name: str, split: str | None) -> YUDSample:
        folder = self.root / name
        image_path = folder / f"{name}.jpg"
        if not image_path.is_file():
            raise FileNotFoundError(f"York Urban DB image not found: {image_path}")
        image = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"cannot decode image {image_path}")
        height, width = int(image.shape[0]), int(image.shape[1])
        suffix, key = GROUND_TRUTHS[self.ground_truth]
        vp = _loadmat(folder / f"{name}{suffix}.mat", [key])[key]
        R = rotation_from_yud_vps(vp)
        K = self.K.clone()
        up = -R[:, 1]
        zenith = zenith_from_up(K[None], up[None])[0]
        horizon = horizon_from_zenith(K[None], zenith[None])[0]
        pitch, roll = pitch_roll_from_up(up[None])
        f = torch.tensor([self.focal], dtype=torch.float64)
        return YUDSample(
            name=name,
            split=split,
            image_path=image_path,
            lines_path=folder / f"{name}LinesAndVP.mat",
            height=height,
            width=width,
            K=K,
            R=R,
            up=up,
            zenith=zenith,
            horizon=horizon,
            vps=(K @ R).T.contiguous(),
            pitch=float(pitch[0]),
            roll=float(roll[0]),
            focal=self.focal,
            fov_v=float(fov_from_focal(f, height)[0]),
            fov_h=float(fov_from_focal(f, width)[0]),
        )

    @property
    def names(self) -> list[str]:
        """Names of the images present, in order."""
        return [s.name for s in self.samples]

    def __len__(self) -> int:
        return len(self.samples)

    @overload
    def __getitem__(self, index: int) -> YUDSample: ...

    @overload
    def __getitem__(self, index: slice) -> list[YUDSample]: ...

    def __getitem__(self, index: int | slice) -> YUDSample | list[YUDSample]:
        return self.samples[index]

    def __iter__(self) -> Iterator[YUDSample]:
        return iter(self.samples)

    def __repr__(self) -> str:
        return f"YorkUrbanDB(root={str(self.root)!r}, split={self.split!r}, images={len(self)})"
