"""Reader for NYU-VP: real indoor scenes (NYU Depth v2) as LSD segments with hand-labelled vanishing points and the
hand-labelled segments of each (Kluger et al., "CONSAC", CVPR 2020, on NYU Depth v2, Silberman et al., ECCV 2012).

The set holds no pixels: each scene is what was measured on a 640x480 photo. Expected layout under ``root``::

    data/vps_NNNN.csv             idx X Y: one labelled vanishing point per row, pixels (may lie far outside)
    data/lsd_lines_NNNN.csv       the LSD segments: line_hom_a b c, centroid x y z, point1 x y z, point2 x y z
    data/labelled_lines_NNNN.csv  idx, then x1 y1 x2 y2 per labelled segment, one row per vanishing point

(space-separated, with a header row; ``NNNN`` the scene number). Every scene shares one camera, NYU Depth v2's RGB
calibration (:data:`NYU_K`).

Ground truth of the horizon, as the set's README defines it: the zenith direction is ``K^-1 v`` (normalised) of the
labelled vanishing point whose direction is closest to the image's vertical axis, provided its unit direction has
``|y| >= 0.8`` (scenes without one have no horizon truth: :attr:`NYUVPSample.up` is None); the horizon is
``K^-T d_up``. Coordinates are taken as given (x right, y down, origin at the top-left).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry.camera import fov_from_focal, horizon_from_zenith, pitch_roll_from_up

__all__ = ["NYU_K", "NYU_SIZE", "NYUVP", "NYUVPSample", "TRAIN_SCENES", "VALIDATION_SCENES", "nyu_up"]

#: NYU Depth v2's RGB camera (fx, fy, cx, cy in pixels), shared by every scene
NYU_K = torch.tensor([[518.858, 0.0, 325.582], [0.0, 519.470, 253.736], [0.0, 0.0, 1.0]], dtype=torch.float64)
#: the photos' size, (height, width)
NYU_SIZE = (480, 640)
#: the set's own splits: train on the first, decide on the second (its test split is not part of this reader's data)
TRAIN_SCENES = range(0, 1000)
VALIDATION_SCENES = range(1000, 1224)
#: the least |y| of the unit direction of a vanishing point taken as the vertical one
VERTICAL_MIN_Y = 0.8


@dataclass(frozen=True)
class NYUVPSample:
    """One NYU-VP scene (float64 tensors, pixels, degrees).

    Attributes:
        name: ``"nyu-NNNN"``.
        index: the scene number.
        height: 480.
        width: 640.
        segments: (N, 2, 2) the LSD segments ``[[x1, y1], [x2, y2]]``.
        vps: (V, 3) the labelled vanishing points, homogeneous pixels ``(x, y, 1)``.
        labelled: one (M_v, 2, 2) tensor of hand-labelled segments per vanishing point, in the order of ``vps``.
        K: (3, 3) the camera (:data:`NYU_K`).
        vertical: index into ``vps`` of the vertical vanishing point, or None.
        up: (3,) unit up vector in camera coordinates (``y <= 0``), or None without a vertical.
        zenith: (3,) ``K @ up``, or None.
        horizon: (3,) ``K^-T up`` with ``a^2 + b^2 = 1``, ``b >= 0``, or None.
        pitch: degrees (> 0 looking up), or None.
        roll: degrees, or None.
        fov_v: the vertical field of view, degrees.
    """

    name: str
    index: int
    height: int
    width: int
    segments: Tensor
    vps: Tensor
    labelled: tuple[Tensor, ...]
    K: Tensor
    vertical: int | None
    up: Tensor | None
    zenith: Tensor | None
    horizon: Tensor | None
    pitch: float | None
    roll: float | None
    fov_v: float


def _rows(path: Path) -> list[list[str]]:
    if not path.is_file():
        raise FileNotFoundError(f"NYU-VP file not found: {path}")
    lines = path.read_text().splitlines()
    if not lines:
        raise ValueError(f"{path}: empty file (expected a header row)")
    return [line.split() for line in lines[1:] if line.strip()]


def _numbers(path: Path, row: list[str], lineno: int) -> list[float]:
    try:
        values = [float(v) for v in row]
    except ValueError as e:
        raise ValueError(f"{path}, line {lineno}: {e}") from e
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{path}, line {lineno}: a value is not finite")
    return values


def _read_vps(path: Path) -> Tensor:
    rows = [_numbers(path, r, i + 2) for i, r in enumerate(_rows(path))]
    if not rows or any(len(r) != 3 for r in rows):
        raise ValueError(f"{path}: expected rows 'idx X Y', at least one")
    xy = torch.tensor([r[1:] for r in rows], dtype=torch.float64)
    return torch.cat([xy, torch.ones(len(rows), 1, dtype=torch.float64)], -1)


def _read_segments(path: Path) -> Tensor:
    rows = [_numbers(path, r, i + 2) for i, r in enumerate(_rows(path))]
    if any(len(r) != 12 for r in rows):
        raise ValueError(f"{path}: expected 12 values a row (line, centroid, two end points)")
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 12)
    return torch.from_numpy(np.stack([a[:, 6:8], a[:, 9:11]], 1))


def _read_labelled(path: Path, count: int) -> tuple[Tensor, ...]:
    rows = [_numbers(path, r, i + 2) for i, r in enumerate(_rows(path))]
    out = [torch.zeros(0, 2, 2, dtype=torch.float64) for _ in range(count)]
    for i, row in enumerate(rows):
        index, values = int(row[0]), row[1:]
        if not 0 <= index < count or len(values) % 4:
            raise ValueError(f"{path}, line {i + 2}: expected a vanishing point index below {count} and x1 y1 x2 y2 "
                             "groups")
        out[index] = torch.tensor(values, dtype=torch.float64).reshape(-1, 2, 2)
    return tuple(out)


def nyu_up(vps: Tensor, K: Tensor = NYU_K) -> tuple[int | None, Tensor | None]:
    """The vertical vanishing point of a scene and the up vector it gives (see the module's docstring).

    Args:
        vps: (V, 3) homogeneous vanishing points in pixels.
        K: (3, 3) intrinsics.

    Returns:
        the index of the vertical one and the (3,) unit up vector (``y <= 0``), or ``(None, None)`` when no
        direction has ``|y| >= 0.8``.

    Example:
        >>> index, up = nyu_up(torch.tensor([[2000.0, 250.0, 1.0], [330.0, -9000.0, 1.0]], dtype=torch.float64))
        >>> index, round(float(up[1]), 3)
        (1, -0.998)
    """
    d = torch.linalg.solve(K, vps.T).T
    d = d / d.norm(dim=-1, keepdim=True)
    steep = d[:, 1].abs()
    best = int(steep.argmax())
    if float(steep[best]) < VERTICAL_MIN_Y:
        return None, None
    up = d[best]
    return best, up if float(up[1]) <= 0 else -up


class NYUVP:
    """The scenes of an NYU-VP folder, as :class:`NYUVPSample`.

    Args:
        root: the folder holding ``data/``.
        scenes: scene numbers to read (e.g. :data:`TRAIN_SCENES`, :data:`VALIDATION_SCENES`); None: every scene
            whose ``vps`` file is there, in order.

    Raises:
        FileNotFoundError: the folder, or a file of a scene asked for, is missing.

    Example:
        >>> NYUVP("no/such/folder")
        Traceback (most recent call last):
        ...
        FileNotFoundError: NYU-VP folder not found: no/such/folder (expected data/vps_NNNN.csv files in it)
    """

    def __init__(self, root: str | Path, scenes: Iterable[int] | None = None) -> None:
        self.root = Path(root)
        data = self.root / "data"
        if not data.is_dir():
            raise FileNotFoundError(f"NYU-VP folder not found: {root} (expected data/vps_NNNN.csv files in it)")
        if scenes is None:
            scenes = sorted(int(p.stem.split("_")[-1]) for p in data.glob("vps_*.csv"))
        self.scenes = [int(s) for s in scenes]

    def __len__(self) -> int:
        return len(self.scenes)

    def __iter__(self) -> Iterator[NYUVPSample]:
        return (self[i] for i in range(len(self)))

    def __getitem__(self, i: int) -> NYUVPSample:
        return self.scene(self.scenes[i])

    def scene(self, index: int) -> NYUVPSample:
        """The sample of scene number ``index``."""
        data, tag = self.root / "data", f"{index:04d}"
        vps = _read_vps(data / f"vps_{tag}.csv")
        vertical, up = nyu_up(vps)
        zenith = horizon = pitch = roll = None
        if up is not None:
            zenith = NYU_K @ up
            horizon = horizon_from_zenith(NYU_K[None], zenith[None])[0]
            pitch, roll = (float(v) for v in pitch_roll_from_up(up[None]))
        height, width = NYU_SIZE
        return NYUVPSample(
            name=f"nyu-{tag}", index=index, height=height, width=width,
            segments=_read_segments(data / f"lsd_lines_{tag}.csv"), vps=vps,
            labelled=_read_labelled(data / f"labelled_lines_{tag}.csv", len(vps)), K=NYU_K.clone(),
            vertical=vertical, up=up, zenith=zenith, horizon=horizon, pitch=pitch, roll=roll,
            fov_v=float(fov_from_focal(NYU_K[1, 1], height)),
        )
