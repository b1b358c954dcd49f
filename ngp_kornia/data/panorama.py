r"""Perspective crops of equirectangular panoramas: the paper's training and test data generation.

The Neural Geometric Parser is trained on perspective images cut out of street-view and SUN360 panoramas with a
random field of view, pitch and roll (Sec. 5 of the paper: FoV 40-80, pitch -30-40, roll -20-20 degrees). This
module makes such crops with ``torch.nn.functional.grid_sample`` (batched, differentiable with respect to the
panorama, any device and float dtype) and gives their ground truth in the conventions of
:mod:`ngp_kornia.geometry.camera`.

Panorama convention (equirectangular, ``Hp`` rows and ``Wp`` columns, any aspect ratio, usually ``Wp = 2 Hp``):

* The world frame is this package's: x and z horizontal, y pointing **down**, so the world up is ``(0, -1, 0)``.
  A world direction ``d`` has longitude ``atan2(d_x, d_z)`` and latitude ``asin(-d_y)``.
* Longitude grows to the right, from -180 degrees at the left border (``x = -0.5``) to +180 at the right border
  (``x = Wp - 0.5``); the image centre column ``x = (Wp - 1) / 2`` is longitude 0, the world +z direction.
  Longitude +90 (a quarter of the width right of the centre) is the world +x direction.
* Latitude is +90 (straight up) at the top border ``y = -0.5`` and -90 at the bottom border ``y = Hp - 0.5``;
  the middle row is the horizon.
* A camera with ``yaw`` looks at longitude ``yaw``: yaw 0 looks at the centre column, yaw 90 at world +x.

The two ends of a row are neighbours on the sphere: the panorama is padded with columns copied from the opposite
side before sampling, so a crop across the seam (yaw near 180) has no artefact.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.geometry import create_meshgrid
from kornia.geometry.camera import unproject_points
from torch import Tensor

from ngp_kornia.geometry.camera import (
    focal_from_fov,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    rotation_from_angles,
    up_from_rotation,
    vanishing_points_from_rotation,
    zenith_from_up,
)

__all__ = [
    "FOV_RANGE",
    "PITCH_RANGE",
    "ROLL_RANGE",
    "crop_ground_truth",
    "crop_rays",
    "panorama_directions",
    "perspective_crops",
    "sample_crop_params",
]

FOV_RANGE = (40.0, 80.0)
PITCH_RANGE = (-30.0, 40.0)
ROLL_RANGE = (-20.0, 20.0)

_MODES = ("bilinear", "nearest", "bicubic")
_PAD = 2  # columns copied across the seam on each side: enough for the 4x4 bicubic kernel


def _check_size(size: tuple[int, int]) -> tuple[int, int]:
    if len(size) != 2 or any(int(s) != s or s < 1 for s in size):
        raise ValueError(f"size must be the crop's (W, H) in pixels, two positive integers; got {size}")
    return int(size[0]), int(size[1])


def _batch_angles(**angles: Tensor | float) -> dict[str, Tensor]:
    """Angles as (B,) tensors of one shape; scalars and (1,) tensors are broadcast to the batch. Python numbers
    and integer tensors become float64."""
    out = {k: torch.as_tensor(v, dtype=None if isinstance(v, Tensor) else torch.float64) for k, v in angles.items()}
    for name, v in out.items():
        if v.dim() > 1:
            raise ValueError(f"{name} must be a (B,) tensor of degrees or a scalar, got shape {tuple(v.shape)}")
        if not v.is_floating_point():
            out[name] = v.double()
    sizes = {v.numel() for v in out.values() if v.dim() == 1}
    b = max(sizes) if sizes else 1
    if sizes - {1, b}:
        shapes = {k: tuple(v.shape) for k, v in out.items()}
        raise ValueError(f"angle batch sizes do not match: {shapes}; give (B,) tensors or scalars")
    return {k: v.reshape(-1).expand(b) for k, v in out.items()}


def _check_fov(fov_v: Tensor) -> None:
    if not bool(((fov_v > 0) & (fov_v < 180)).all()):
        raise ValueError(f"fov_v_deg must lie in (0, 180) degrees, got {fov_v.tolist()}")


def panorama_directions(height: int, width: int, device=None, dtype: torch.dtype = torch.float32) -> Tensor:
    """Unit world direction of every pixel centre of an equirectangular panorama (see the module docstring).
    Ours: kornia has no equirectangular camera.

    Args:
        height: panorama rows ``Hp``.
        width: panorama columns ``Wp``.
        device: device of the result.
        dtype: float dtype of the result.

    Returns:
        (Hp, Wp, 3) unit directions ``(x, y, z)`` in the world frame (y down).

    Example:
        >>> d = panorama_directions(3, 4)  # the middle row is the horizon; longitudes -135, -45, 45, 135
        >>> d[1].round(decimals=4)
        tensor([[-0.7071, -0.0000, -0.7071],
                [-0.7071, -0.0000,  0.7071],
                [ 0.7071, -0.0000,  0.7071],
                [ 0.7071, -0.0000, -0.7071]])
        >>> d[0, :, 1]  # the top row looks up (latitude 60)
        tensor([-0.8660, -0.8660, -0.8660, -0.8660])
    """
    xy = create_meshgrid(height, width, False, device, dtype)[0]
    lon = ((xy[..., 0] + 0.5) / width * 2.0 - 1.0) * math.pi
    lat = (0.5 - (xy[..., 1] + 0.5) / height) * math.pi
    return torch.stack([lat.cos() * lon.sin(), -lat.sin(), lat.cos() * lon.cos()], -1)


def crop_rays(fov_v_deg: Tensor, pitch: Tensor, roll: Tensor, yaw: Tensor, size: tuple[int, int]) -> Tensor:
    """World direction ``R^T K^-1 p`` of every pixel ``p`` of perspective crops (not normalised): kornia's
    :func:`~kornia.geometry.camera.unproject_points` at depth 1, turned into the world frame.

    Args:
        fov_v_deg: (B,) vertical field of view in degrees.
        pitch: (B,) degrees, > 0 looking up.
        roll: (B,) degrees.
        yaw: (B,) degrees, the longitude the camera looks at.
        size: crop ``(W, H)`` in pixels.

    Returns:
        (B, H, W, 3) rays in the world frame, with the dtype and device of ``fov_v_deg``.

    Example:
        >>> rays = crop_rays(torch.tensor([90.0]), torch.zeros(1), torch.zeros(1), torch.tensor([90.0]), (3, 3))
        >>> rays[0, 1, 1].round(decimals=4).tolist()  # the centre ray of a camera turned right: world +x
        [1.0, 0.0, 0.0]
    """
    W, H = _check_size(size)
    _check_fov(fov_v_deg)
    focal = focal_from_fov(fov_v_deg, H)
    K = intrinsics_matrix(focal, image_center(H, W, like=focal))
    R = rotation_from_angles(pitch.to(focal), roll.to(focal), yaw.to(focal))
    xy = create_meshgrid(H, W, False, focal.device, focal.dtype).reshape(1, -1, 2)  # (1, H*W, 2)
    # K^-1 p: the camera rays at depth z = 1, (B, H*W, 3); then R^T, row by row
    rays = unproject_points(xy, torch.ones_like(xy[..., :1]), K[:, None])
    return (rays @ R).reshape(-1, H, W, 3)


def _sampling_grid(rays: Tensor, height: int, width: int) -> Tensor:
    """grid_sample coordinates (align_corners=False) of world rays in a panorama padded by ``_PAD`` columns (not
    kornia's ``normalize_pixel_coordinates``, which is corner-aligned and takes pixels, not longitude and latitude)."""
    x, y, z = rays.unbind(-1)
    lon = torch.atan2(x, z)  # [-pi, pi]
    lat = torch.atan2(-y, torch.hypot(x, z))
    col = (lon / (2.0 * math.pi) + 0.5) * width - 0.5 + _PAD  # padded pixel column, in [_PAD - 0.5, ...]
    gx = (2.0 * col + 1.0) / (width + 2 * _PAD) - 1.0
    gy = -lat / (0.5 * math.pi)
    return torch.stack([gx, gy], -1)


def _pad_seam(panorama: Tensor) -> Tensor:
    return torch.cat([panorama[..., -_PAD:], panorama, panorama[..., :_PAD]], -1)


def perspective_crops(
    panorama: Tensor,
    fov_v_deg: Tensor | float,
    pitch: Tensor | float,
    roll: Tensor | float,
    yaw: Tensor | float,
    size: tuple[int, int] = (640, 480),
    mode: str = "bilinear",
) -> Tensor:
    """Perspective images of equirectangular panoramas, as the paper's data generation.

    Every crop pixel ``p`` looks along the world ray ``R^T K^-1 p`` with ``K`` the centred pinhole of the vertical
    field of view and ``R = rotation_from_angles(pitch, roll, yaw)``; the ray's longitude and latitude are
    resampled from the panorama. See the module docstring for the panorama convention and
    :func:`crop_ground_truth` for the crops' calibration.

    Args:
        panorama: (B, C, Hp, Wp) float panoramas, or (1, C, Hp, Wp) shared by all crops.
        fov_v_deg: (B,) vertical field of view in degrees, in (0, 180), or a scalar (shared by all crops).
        pitch: (B,) degrees, > 0 looking up, or a scalar.
        roll: (B,) degrees, > 0 when the scene's up leans right in the crop, or a scalar.
        yaw: (B,) degrees, the longitude the camera looks at, or a scalar.
        size: crop ``(W, H)`` in pixels.
        mode: ``"bilinear"``, ``"nearest"`` or ``"bicubic"`` interpolation.

    Returns:
        (B, C, H, W) crops with the panorama's dtype and device.

    Raises:
        ValueError: a panorama that is not (B, C, Hp, Wp) float, mismatched batch sizes, a field of view outside
            (0, 180), a bad size or mode.

    Example:
        >>> pano = torch.rand(1, 3, 64, 128)
        >>> crops = perspective_crops(pano, torch.tensor([60.0, 45.0]), torch.tensor([10.0, -5.0]),
        ...                           torch.tensor([0.0, 3.0]), torch.tensor([0.0, 170.0]), size=(40, 30))
        >>> crops.shape
        torch.Size([2, 3, 30, 40])
    """
    if not isinstance(panorama, Tensor) or panorama.dim() != 4 or not panorama.is_floating_point():
        got = f"{tuple(panorama.shape)} {panorama.dtype}" if isinstance(panorama, Tensor) else type(panorama).__name__
        raise ValueError(f"panorama must be a (B, C, Hp, Wp) float tensor, got {got}; use pano[None].float() / 255")
    if mode not in _MODES:
        raise ValueError(f"mode must be one of {_MODES}, got {mode!r}")
    work = torch.float64 if panorama.dtype == torch.float64 else torch.float32
    angles = _batch_angles(fov_v_deg=fov_v_deg, pitch=pitch, roll=roll, yaw=yaw)
    n, batch = angles["pitch"].shape[0], panorama.shape[0]
    if batch not in (1, n) and n != 1:
        raise ValueError(f"panorama batch {batch} does not match the {n} crop angles; give 1 or {n} panoramas")
    batch = max(batch, n)
    angles = {k: v.to(panorama.device, work).expand(batch) for k, v in angles.items()}
    rays = crop_rays(angles["fov_v_deg"], angles["pitch"], angles["roll"], angles["yaw"], size)
    grid = _sampling_grid(rays, panorama.shape[-2], panorama.shape[-1]).to(panorama.dtype)
    padded = _pad_seam(panorama).expand(batch, -1, -1, -1)
    return F.grid_sample(padded, grid, mode=mode, padding_mode="border", align_corners=False)


def sample_crop_params(
    n: int,
    generator: torch.Generator | None = None,
    fov_range: tuple[float, float] = FOV_RANGE,
    pitch_range: tuple[float, float] = PITCH_RANGE,
    roll_range: tuple[float, float] = ROLL_RANGE,
    yaw_range: tuple[float, float] = (-180.0, 180.0),
    dtype: torch.dtype = torch.float32,
) -> dict[str, Tensor]:
    """Uniformly random crop parameters; the defaults are the paper's ranges (vertical FoV, pitch, roll).

    Args:
        n: number of crops.
        generator: torch random generator (on the CPU) for reproducible draws.
        fov_range: (low, high) vertical field of view in degrees, inside (0, 180).
        pitch_range: (low, high) pitch in degrees.
        roll_range: (low, high) roll in degrees.
        yaw_range: (low, high) yaw in degrees.
        dtype: float dtype of the result.

    Returns:
        A dict of (n,) CPU tensors ``fov_v``, ``pitch``, ``roll``, ``yaw`` in degrees, ready for
        ``perspective_crops(pano, p["fov_v"], p["pitch"], p["roll"], p["yaw"])``.

    Example:
        >>> p = sample_crop_params(4, torch.Generator().manual_seed(0))
        >>> sorted(p), p["fov_v"].shape
        (['fov_v', 'pitch', 'roll', 'yaw'], torch.Size([4]))
        >>> bool(((p["pitch"] >= -30) & (p["pitch"] <= 40)).all())
        True
    """
    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n}")
    ranges = {"fov_v": fov_range, "pitch": pitch_range, "roll": roll_range, "yaw": yaw_range}
    for name, (lo, hi) in ranges.items():
        if not lo <= hi:
            raise ValueError(f"{name}_range must be (low, high) with low <= high, got {(lo, hi)}")
    if not (0 < fov_range[0] and fov_range[1] < 180):
        raise ValueError(f"fov_range must lie inside (0, 180) degrees, got {fov_range}")
    out = {}
    for name, (lo, hi) in ranges.items():
        u = torch.rand(int(n), generator=generator, dtype=torch.float64)
        out[name] = (lo + (hi - lo) * u).to(dtype)
    return out


def crop_ground_truth(
    fov_v: Tensor | float, pitch: Tensor | float, roll: Tensor | float, yaw: Tensor | float, size: tuple[int, int]
) -> dict[str, Tensor]:
    """Calibration ground truth of perspective crops, with the field names of
    :class:`ngp_kornia.pipeline.result.Calibration`.

    ``R`` is relative to the panorama's world frame (yaw as given), not canonicalised to a Manhattan frame.

    Args:
        fov_v: (B,) vertical field of view in degrees, or a scalar.
        pitch: (B,) degrees, or a scalar.
        roll: (B,) degrees, or a scalar.
        yaw: (B,) degrees, or a scalar.
        size: crop ``(W, H)`` in pixels.

    Returns:
        A dict of batched tensors (float64 unless the angles are another float dtype): ``K`` (B, 3, 3), ``R``
        (B, 3, 3), ``focal``, ``fov_v``, ``fov_h``, ``pitch``, ``roll``, ``yaw`` (B,), ``up`` (B, 3), ``zenith``
        (B, 3) unit norm, ``horizon`` (B, 3) with ``a^2 + b^2 = 1`` and ``b >= 0``, ``vps`` (B, 3, 3) with row
        ``i`` the VP of world axis ``i``, and ``image_size`` (B, 2) ``(H, W)``.

    Example:
        >>> gt = crop_ground_truth(60.0, 0.0, 0.0, 0.0, (640, 480))
        >>> gt["horizon"].tolist()  # level camera: the horizon is the middle row
        [[0.0, 1.0, -239.5]]
        >>> round(float(gt["fov_h"][0]), 2)
        75.18
    """
    W, H = _check_size(size)
    a = _batch_angles(fov_v=fov_v, pitch=pitch, roll=roll, yaw=yaw)
    _check_fov(a["fov_v"])
    focal = focal_from_fov(a["fov_v"], H)
    K = intrinsics_matrix(focal, image_center(H, W, like=focal))
    R = rotation_from_angles(a["pitch"].to(focal), a["roll"].to(focal), a["yaw"].to(focal))
    up = up_from_rotation(R)
    zenith = zenith_from_up(K, up)
    return {
        "K": K,
        "R": R,
        "focal": focal,
        "fov_v": a["fov_v"].clone(),
        "fov_h": fov_from_focal(focal, W),
        "pitch": a["pitch"].to(focal),
        "roll": a["roll"].to(focal),
        "yaw": a["yaw"].to(focal),
        "up": up,
        "zenith": normalize(zenith),
        "horizon": horizon_from_zenith(K, zenith),
        "vps": vanishing_points_from_rotation(K, R),
        "image_size": torch.tensor([[H, W]], device=focal.device).repeat(focal.shape[0], 1),
    }
