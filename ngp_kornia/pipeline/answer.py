"""The answer of the frame search: the top-k average of the best frames (Eq. 23), in the image's pixels, as a
:class:`~ngp_kornia.pipeline.result.Calibration`."""

from __future__ import annotations

import math
from dataclasses import replace

import torch
from torch import Tensor

from ngp_kornia.geometry import (
    Camera,
    FrameCandidates,
    canonical_manhattan_rotation,
    dominant_eigenvector,
    image_center,
    intrinsics_matrix,
    normalize,
    pseudo_focal,
    rotation_from_vps,
    structure_tensor,
    topk_weighted_average,
)
from ngp_kornia.pipeline.constants import constant_tensors
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.settings import ScoringSettings

__all__ = ["calibration_from_camera", "level_answer", "topk_calibration"]


def topk_calibration(
    frames: FrameCandidates,
    scores: Tensor,
    height: int,
    width: int,
    settings: ScoringSettings,
    known_focal: float | Tensor | None = None,
) -> tuple[Calibration, Tensor]:
    """Top-k average (Eq. 23) of the frames' focal lengths and zeniths, yaw from the best frame, mapped to pixels.

    Args:
        frames: (B, F) scored frame candidates (pseudo camera); scores: (B, F), zero for invalid frames.
        height, width: the image's size.
        settings: ``top_k`` and ``fallback_fov``.
        known_focal: a focal-length prior in pseudo-camera units, one for all or (B,): the answer of an image
            without a valid frame.

    Returns:
        the calibration, and the (B, F) top-k weights of its average. An image without a valid frame gets a level
        camera with ``known_focal`` or the ``fallback_fov`` and ``valid=False``.
    """
    valid = frames.valid.any(-1)
    focal, top_k_weights = topk_weighted_average(scores, frames.focal, settings.top_k, frames.valid)
    # the zenith's average has the same weights: the top-k average of the structure tensors, without ranking again
    zenith = dominant_eigenvector(_weighted_zenith_tensor(frames.zenith, top_k_weights, settings.top_k))
    best = scores.argmax(-1)
    horizontal = frames.horizontal.gather(1, best[:, None, None].expand(-1, 1, 3))[:, 0]
    if known_focal is None:
        fallback = 1.0 / math.tan(math.radians(settings.fallback_fov) / 2.0)
    else:
        fallback = torch.as_tensor(known_focal, dtype=focal.dtype, device=focal.device)
    focal = torch.where(valid, focal, fallback)
    level, ahead = constant_tensors(((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)), zenith.dtype, zenith.device)
    zenith = torch.where(valid[:, None], zenith, level)
    horizontal = torch.where(valid[:, None], horizontal, ahead)
    # the pseudo camera has K = diag(f, f, 1); pixels need K_p = [[f_p, 0, c], [0, f_p, c], [0, 0, 1]]
    K_unit = intrinsics_matrix(focal, constant_tensors(((0.0, 0.0),), focal.dtype, focal.device)[0])
    R = canonical_manhattan_rotation(rotation_from_vps(K_unit, zenith, horizontal))
    f_px = focal * pseudo_focal(height, width)
    K = intrinsics_matrix(f_px, image_center(height, width, like=f_px))
    return calibration_from_camera(K, R, scores.amax(-1), valid, height, width), top_k_weights


def calibration_from_camera(
    K: Tensor, R: Tensor, score: Tensor, valid: Tensor, height: int, width: int
) -> Calibration:
    """The :class:`Calibration` of cameras ``K`` (B, 3, 3), ``R`` (B, 3, 3) in an image of ``height`` x ``width``:
    up, zenith, horizon, VPs, pitch / roll / yaw and both fields of view follow from ``K`` and ``R``
    (:class:`~ngp_kornia.geometry.pinhole.Camera`); ``score`` (B,) and ``valid`` (B,) are carried as they are.

    Example:
        >>> K = torch.tensor([[[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]]])
        >>> cal = calibration_from_camera(K, torch.eye(3)[None], torch.ones(1), torch.ones(1, dtype=torch.bool),
        ...                               480, 640)
        >>> cal.horizon.tolist(), round(float(cal.fov_v), 2)
        ([[0.0, 1.0, -239.5]], 51.28)
    """
    size = torch.tensor([height, width], device=K.device).expand(len(K), 2)
    camera = Camera.from_matrix(K, R, size)
    exif = torch.ones(len(K), dtype=torch.long, device=K.device)  # tensors are taken as they are
    return Calibration(camera=camera, score=score, valid=valid, exif_orientation=exif)


def level_answer(result: Calibration, where: Tensor, fallback_fov: float) -> Calibration:
    """The answer with the (batched) images ``where`` (B,) bool given the answer of an image without evidence: a
    level camera (pitch, roll and yaw 0) with a known focal length (``fov_v_std`` 0) or else ``fallback_fov``
    degrees on the long side, at the answer's principal point. What :func:`topk_calibration` gives an image
    without a valid frame, for an image that another check finds without evidence.

    Example:
        >>> K = torch.tensor([[[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]])
        >>> R = torch.linalg.matrix_exp(torch.tensor([[[0.0, -0.2, 0.1], [0.2, 0, 0], [-0.1, 0, 0]]]))  # rolled
        >>> answer = calibration_from_camera(K, R, torch.ones(1), torch.ones(1, dtype=torch.bool), 480, 640)
        >>> level = level_answer(answer, torch.tensor([True]), 60.0)
        >>> [round(float(v), 2) for v in (level.pitch, level.roll, level.yaw, level.fov_h)]
        [0.0, 0.0, 0.0, 60.0]
    """
    if not bool(where.any()):
        return result
    height, width = (int(v) for v in result.image_size[0])
    fallback = max(height, width) / 2.0 / math.tan(math.radians(fallback_fov) / 2.0)
    known = torch.zeros_like(where) if result.fov_v_std is None else result.fov_v_std == 0
    focal = torch.where(known, result.focal, torch.full_like(result.focal, fallback))
    params = result.camera.params
    level = torch.stack([focal, focal, params[:, 2], params[:, 3]], -1)  # the principal point kept
    eye = torch.eye(3, dtype=result.R.dtype, device=result.R.device).expand_as(result.R)
    camera = result.camera.replace(params=torch.where(where[:, None], level, params),
                                   R=torch.where(where[:, None, None], eye, result.R))
    return replace(result, camera=camera)


def _weighted_zenith_tensor(zenith: Tensor, weights: Tensor, k: int) -> Tensor:
    """``(weights[..., None, None] * structure_tensor(zenith)).sum(1)`` for (B, F) weights that are zero outside their
    top ``k``: the tensors of those k frames only, laid among zeros so that the sum adds the same values in the same
    order (the F tensors cost 0.25 ms on the parser's 1536 frames).

    The rows are normalised as torch normalises ``zenith`` (B, F, 3) in its layout: where a row's entries are not
    adjacent (the frames' zeniths are columns of their VP matrices) it sums the squares in order and takes a
    correctly rounded root; where they are, fused multiply-adds, which :func:`normalize` of the gathered rows repeats.
    """
    B, F = weights.shape
    if F <= k or (zenith.stride(-1) != 1 and zenith.dtype != torch.float32):  # the root below is float32's
        return (weights[..., None, None] * structure_tensor(zenith)).sum(1)
    index = weights.topk(k, dim=1).indices  # every frame with weight (and some without)
    rows = zenith.gather(1, index[..., None].expand(B, k, 3))
    if zenith.stride(-1) == 1:
        unit = normalize(rows)
    else:
        sq = rows * rows
        norm = (sq[..., 0] + sq[..., 1] + sq[..., 2]).double().sqrt_().float()
        unit = rows / norm[..., None].clamp_min(torch.finfo(rows.dtype).eps)
    tensors = weights.gather(1, index)[..., None, None] * (unit.unsqueeze(-1) * unit.unsqueeze(-2))
    return tensors.new_zeros(B, F, 3, 3).scatter_(1, index[..., None, None].expand(B, k, 3, 3), tensors).sum(1)
