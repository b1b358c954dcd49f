r"""Evaluation metrics for single-image calibration: up vector, pitch, roll, field of view, rotation, horizon.

Every error function is batched: inputs carry a leading batch dimension ``B`` and the output has shape (B,).
Angles are in degrees. The horizon metric is the one used by the Neural Geometric Parser (Lee et al.,
ECCV 2020) after Barinova et al. (ECCV 2010) and Workman et al. (BMVC 2016): the largest vertical distance
between the predicted and true horizon over the left and right image borders, divided by the image height.
Its summary is the area under the cumulative error curve on ``[0, 0.25]`` (:func:`horizon_auc`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from kornia.metrics import angle_error_mat
from torch import Tensor

from ngp_kornia.geometry.camera import horizon_border_points, horizon_from_zenith, image_center, intrinsics_matrix
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.geometry.line_algebra import pseudo_focal

__all__ = [
    "angle_error_between_rotations",
    "fov_error",
    "frame_horizon_error",
    "frame_horizons",
    "horizon_auc",
    "horizon_error",
    "pitch_error",
    "roll_error",
    "summarize",
    "up_vector_error",
    "zenith_error_deg",
]


def _check_tensor(x: object, name: str) -> Tensor:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    return x


def _check_same_shape(pred: Tensor, gt: Tensor, names: tuple[str, str]) -> None:
    _check_tensor(pred, names[0])
    _check_tensor(gt, names[1])
    if pred.shape != gt.shape:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same shape, "
            f"got {tuple(pred.shape)} and {tuple(gt.shape)}"
        )


def _per_image(value: int | float | Tensor, like: Tensor, name: str) -> Tensor:
    """An image size given as a number or a (B,) tensor, as a (B,) tensor like ``like``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, Tensor)):
        raise TypeError(f"{name} must be a number or a (B,) tensor, got {type(value).__name__}")
    t = torch.as_tensor(value).to(like)
    if t.dim() > 1 or (t.dim() == 1 and t.shape[0] != like.shape[0]):
        raise ValueError(
            f"{name} must be a number or a tensor of shape ({like.shape[0]},), got {tuple(t.shape)}"
        )
    if not bool((t > 0).all()):
        raise ValueError(f"{name} must be positive")
    return t.expand(like.shape[0])


def up_vector_error(up_pred: Tensor, up_gt: Tensor) -> Tensor:
    """Angle in degrees between predicted and true up vectors.

    The vectors are compared with their sign (both are meant to point up), so the error lies in [0, 180].
    The angle is computed as ``2 atan2(|u - v|, |u + v|)`` on unit vectors, which is exact near 0 and 180
    degrees where ``acos`` of the cosine loses precision. A zero vector carries no direction and scores
    90 degrees; the result is always finite. Not kornia's ``angle_error_vec``: it is NaN for a zero vector, and its
    cross product leaves a rounding residue (about 1e-6 degrees in float32) between identical vectors.

    Args:
        up_pred: (B, 3) predicted up vectors (any positive length).
        up_gt: (B, 3) true up vectors.

    Returns:
        (B,) angles in degrees.

    Example:
        >>> up_vector_error(torch.tensor([[0.0, -1.0, 0.0], [0.0, -1.0, 0.0]]),
        ...                 torch.tensor([[0.0, -2.0, 0.0], [1.0, -1.0, 0.0]]))
        tensor([ 0., 45.])
    """
    _check_same_shape(up_pred, up_gt, ("up_pred", "up_gt"))
    KORNIA_CHECK_SHAPE(up_pred, ["B", "3"])
    if not (up_pred.is_floating_point() and up_gt.is_floating_point()):
        raise TypeError(f"up vectors must be floating point tensors, got {up_pred.dtype} and {up_gt.dtype}")
    up_gt = up_gt.to(up_pred)
    n_pred, n_gt = up_pred.norm(dim=-1, keepdim=True), up_gt.norm(dim=-1, keepdim=True)
    tiny = torch.finfo(up_pred.dtype).tiny
    u, v = up_pred / n_pred.clamp_min(tiny), up_gt / n_gt.clamp_min(tiny)
    angle = torch.rad2deg(2.0 * torch.atan2((u - v).norm(dim=-1), (u + v).norm(dim=-1)))
    degenerate = (n_pred.squeeze(-1) <= tiny) | (n_gt.squeeze(-1) <= tiny)
    return torch.where(degenerate, torch.full_like(angle, 90.0), angle)


def pitch_error(pitch_pred: Tensor, pitch_gt: Tensor) -> Tensor:
    """Absolute pitch difference in degrees.

    Args:
        pitch_pred: (B,) predicted pitch in degrees.
        pitch_gt: (B,) true pitch in degrees.

    Returns:
        (B,) absolute differences.

    Example:
        >>> pitch_error(torch.tensor([10.0, -3.0]), torch.tensor([4.0, 2.0]))
        tensor([6., 5.])
    """
    _check_same_shape(pitch_pred, pitch_gt, ("pitch_pred", "pitch_gt"))
    KORNIA_CHECK_SHAPE(pitch_pred, ["B"])
    return (pitch_pred - pitch_gt).abs()


def roll_error(roll_pred: Tensor, roll_gt: Tensor) -> Tensor:
    """Absolute roll difference in degrees, wrapped so that it lies in [0, 180] (179 and -179 are 2 apart).

    Args:
        roll_pred: (B,) predicted roll in degrees.
        roll_gt: (B,) true roll in degrees.

    Returns:
        (B,) wrapped absolute differences.

    Example:
        >>> roll_error(torch.tensor([10.0, 179.0]), torch.tensor([0.0, -179.0]))
        tensor([10.,  2.])
    """
    _check_same_shape(roll_pred, roll_gt, ("roll_pred", "roll_gt"))
    KORNIA_CHECK_SHAPE(roll_pred, ["B"])
    d = torch.remainder(roll_pred - roll_gt + 180.0, 360.0) - 180.0
    return d.abs()


def fov_error(fov_pred: Tensor, fov_gt: Tensor) -> Tensor:
    """Absolute field-of-view difference in degrees.

    Args:
        fov_pred: (B,) predicted field of view in degrees.
        fov_gt: (B,) true field of view in degrees.

    Returns:
        (B,) absolute differences.

    Example:
        >>> fov_error(torch.tensor([50.0]), torch.tensor([45.5]))
        tensor([4.5000])
    """
    _check_same_shape(fov_pred, fov_gt, ("fov_pred", "fov_gt"))
    KORNIA_CHECK_SHAPE(fov_pred, ["B"])
    return (fov_pred - fov_gt).abs()


def angle_error_between_rotations(R_pred: Tensor, R_gt: Tensor) -> Tensor:
    """Geodesic angle in degrees of ``R_pred^T R_gt``: :func:`kornia.metrics.angle_error_mat`.

    The angle is ``atan2(sin, cos)`` with the sine read from the skew part of ``R_pred^T R_gt`` and the cosine from
    its trace, which is accurate for small angles and finite even for matrices that are only approximately
    rotations. No Manhattan (axis permutation) symmetry is applied.

    Args:
        R_pred: (B, 3, 3) predicted rotations.
        R_gt: (B, 3, 3) true rotations.

    Returns:
        (B,) angles in degrees, in [0, 180].

    Example:
        >>> from ngp_kornia.geometry.camera import rotation_from_angles
        >>> R1 = rotation_from_angles(torch.tensor([0.0]), torch.tensor([0.0]))
        >>> R2 = rotation_from_angles(torch.tensor([0.0]), torch.tensor([30.0]))
        >>> angle_error_between_rotations(R1, R2)
        tensor([30.0000])
    """
    _check_same_shape(R_pred, R_gt, ("R_pred", "R_gt"))
    KORNIA_CHECK_SHAPE(R_pred, ["B", "3", "3"])
    return angle_error_mat(R_pred, R_gt)


def horizon_error(
    horizon_pred: Tensor, horizon_gt: Tensor, height: int | float | Tensor, width: int | float | Tensor
) -> Tensor:
    """Horizon error: the largest vertical distance between the two horizons at the left (``x = -0.5``) and
    right (``x = W - 0.5``) image borders, divided by the image height.

    Args:
        horizon_pred: (B, 3) predicted horizon lines ``(a, b, c)`` in pixels (any scale and sign).
        horizon_gt: (B, 3) true horizon lines in pixels.
        height: image height in pixels, a number or a (B,) tensor.
        width: image width in pixels, a number or a (B,) tensor.

    Returns:
        (B,) errors as a fraction of the image height.

    Example:
        >>> gt = torch.tensor([[0.0, 1.0, -240.0]])          # y = 240
        >>> pred = torch.tensor([[0.0, -2.0, 2 * 288.0]])    # y = 288, opposite sign and another scale
        >>> horizon_error(pred, gt, 480, 640)
        tensor([0.1000])
    """
    _check_same_shape(horizon_pred, horizon_gt, ("horizon_pred", "horizon_gt"))
    KORNIA_CHECK_SHAPE(horizon_pred, ["B", "3"])
    if not horizon_pred.is_floating_point():
        raise TypeError(f"horizon_pred must be a floating point tensor, got {horizon_pred.dtype}")
    h = _per_image(height, horizon_pred, "height")
    w = _per_image(width, horizon_pred, "width")
    y_pred = horizon_border_points(horizon_pred, w)[..., 1]
    y_gt = horizon_border_points(horizon_gt.to(horizon_pred), w)[..., 1]
    return (y_pred - y_gt).abs().amax(dim=-1) / h


def horizon_auc(errors: Tensor | Sequence[float], max_error: float = 0.25) -> Tensor:
    """Area under the cumulative distribution of horizon errors on ``[0, max_error]``, normalised to [0, 1].

    This is the exact integral ``(1 / max_error) * int_0^max_error F(e) de`` of the empirical CDF
    ``F(e) = #{errors <= e} / N``, which equals the mean over the images of
    ``max(0, max_error - e_i) / max_error``. A perfect estimator scores 1. A NaN or infinite error (a failed
    estimate) counts as larger than ``max_error``.

    Args:
        errors: (N,) horizon errors, e.g. from :func:`horizon_error`; a sequence of floats is accepted too.
        max_error: upper end of the integration interval.

    Returns:
        0-dim tensor with the normalised area.

    Example:
        >>> horizon_auc(torch.tensor([0.0, 0.125, 0.3]))
        tensor(0.5000)
    """
    if not isinstance(errors, Tensor):
        if isinstance(errors, (str, bytes)) or not isinstance(errors, Sequence):
            raise TypeError(f"errors must be a tensor or a sequence of floats, got {type(errors).__name__}")
        errors = torch.as_tensor(list(errors), dtype=torch.float64)
    if not (isinstance(max_error, (int, float)) and max_error > 0):
        raise ValueError(f"max_error must be a positive number, got {max_error!r}")
    KORNIA_CHECK_SHAPE(errors, ["N"])
    if errors.numel() == 0:
        raise ValueError("horizon_auc needs at least one error")
    e = errors if errors.is_floating_point() else errors.double()
    if bool((e < 0).any()):
        raise ValueError("horizon errors must be non-negative")
    e = torch.where(torch.isfinite(e), e, torch.full_like(e, float(max_error)))
    return ((max_error - e).clamp_min(0.0) / max_error).mean()


def summarize(errors: Tensor | Sequence[float]) -> dict[str, float]:
    """Mean, median and count of a set of errors (the median is the midpoint of the two central values).

    NaN values propagate to the mean and median, so failures are never hidden.

    Args:
        errors: (N,) errors.

    Returns:
        ``{"mean": float, "median": float, "count": int}``; mean and median are NaN for an empty input.

    Example:
        >>> summarize(torch.tensor([1.0, 2.0, 4.0, 10.0]))
        {'mean': 4.25, 'median': 3.0, 'count': 4}
    """
    if not isinstance(errors, Tensor):
        if isinstance(errors, (str, bytes)) or not isinstance(errors, Sequence):
            raise TypeError(f"errors must be a tensor or a sequence of floats, got {type(errors).__name__}")
        errors = torch.as_tensor(list(errors), dtype=torch.float64)
    KORNIA_CHECK_SHAPE(errors, ["N"])
    n = int(errors.numel())
    if n == 0:
        return {"mean": math.nan, "median": math.nan, "count": 0}
    e = errors.double()
    if bool(torch.isnan(e).any()):
        return {"mean": math.nan, "median": math.nan, "count": n}
    return {"mean": float(e.mean()), "median": float(torch.quantile(e, 0.5)), "count": n}


def frame_horizons(frames: FrameCandidates, height: int, width: int) -> Tensor:
    """The horizon line of each frame candidate in pixels, from its zenith and focal length (pseudo camera).
    Ours: the zenith is homogeneous (it may lie at infinity), where kornia's point conversions are Euclidean.

    The candidate's camera is ``K = [[f fp, 0, cx], [0, f fp, cy], [0, 0, 1]]`` with ``fp`` = :func:`pseudo_focal`
    and ``(cx, cy)`` the image centre; its zenith in pixels is ``K_p z`` with ``K_p`` the pseudo camera. Invalid
    frames (focal 0) use focal 1 so the result stays finite.

    Returns:
        (B, F, 3) lines ``(a, b, c)`` in pixels.

    Example:
        >>> fr = FrameCandidates(torch.tensor([[[0.0, 1.0, 0.0]]]), None, torch.ones(1, 1), None, None, None)
        >>> frame_horizons(fr, 480, 640)  # level camera: the horizon is the row through the centre
        tensor([[[   0.0000,    1.0000, -239.5000]]])
    """
    KORNIA_CHECK_SHAPE(frames.zenith, ["B", "F", "3"])
    KORNIA_CHECK_SHAPE(frames.focal, ["B", "F"])
    z = frames.zenith
    fp = pseudo_focal(height, width)
    c = image_center(height, width, like=z)
    focal = torch.where(frames.focal > 0, frames.focal, torch.ones_like(frames.focal)).to(z)
    zenith_px = torch.cat([z[..., :2] * fp + c * z[..., 2:], z[..., 2:]], -1)
    K = intrinsics_matrix(focal.flatten() * fp, c)
    return horizon_from_zenith(K, zenith_px.flatten(0, 1)).reshape(z.shape)


def frame_horizon_error(frames: FrameCandidates, horizon_gt: Tensor, height: int, width: int) -> Tensor:
    """Horizon error of each candidate (Barinova et al.): the larger L1 distance between the candidate's and the
    true horizon's crossings of the left and right image borders, divided by the image height.

    Args:
        frames: (B, F) candidates in the pseudo camera.
        horizon_gt: (B, 3) true horizon line in pixels.
        height: image height in pixels.
        width: image width in pixels.

    Returns:
        (B, F) errors in image heights.

    Example:
        >>> fr = FrameCandidates(torch.tensor([[[0.0, 1.0, 0.0]]]), None, torch.ones(1, 1), None, None, None)
        >>> frame_horizon_error(fr, torch.tensor([[0.0, 1.0, -287.5]]), 480, 640)  # 48 px = 0.1 heights lower
        tensor([[0.1000]])
    """
    KORNIA_CHECK_SHAPE(horizon_gt, ["B", "3"])
    h = horizon_border_points(frame_horizons(frames, height, width), width)  # (B, F, 2, 2)
    g = horizon_border_points(horizon_gt.to(h), width)[:, None]  # (B, 1, 2, 2)
    return (h - g).abs().sum(-1).amax(-1) / height




def zenith_error_deg(zenith: Tensor, zenith_gt: Tensor, focal: Tensor) -> Tensor:
    """Angle in degrees between the up directions of two zeniths given in the pseudo camera, using the true focal
    length. Sign-free: a zenith and its negative are the same direction (kornia's ``angle_error_vec`` is not).

    Args:
        zenith: (B, 3) estimated zenith VPs, homogeneous, in the pseudo camera.
        zenith_gt: (B, 3) true zenith VPs in the pseudo camera.
        focal: (B,) true focal length in pseudo-camera units.

    Returns:
        (B,) angles in degrees, in [0, 90].

    Example:
        >>> zenith_error_deg(torch.tensor([[0.0, 1.0, 0.0]]), torch.tensor([[0.0, -1.0, 0.0]]), torch.ones(1))
        tensor([0.])
    """
    scale = torch.stack([1.0 / focal, 1.0 / focal, torch.ones_like(focal)], -1)
    a = torch.nn.functional.normalize(zenith * scale, dim=-1)
    b = torch.nn.functional.normalize(zenith_gt * scale, dim=-1)
    cos = (a * b).sum(-1).abs().clamp(max=1.0)
    return torch.rad2deg(torch.atan2((1 - cos**2).clamp_min(0).sqrt(), cos))
