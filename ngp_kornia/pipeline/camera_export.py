"""A calibration as the camera types of the tools around it: kornia's ``PinholeCamera``, OpenCV's ``(K, dist)``
and COLMAP's ``SIMPLE_PINHOLE`` / ``PINHOLE`` cameras (the ``Calibration.to_*`` methods call these).

Pixel conventions: ours, kornia's and OpenCV's put the origin at the *centre* of the top-left pixel, so a centred
principal point is ``((W - 1) / 2, (H - 1) / 2)``. COLMAP puts the origin at the top-left *corner* of the image
(the centre of the top-left pixel is ``(0.5, 0.5)``), so every pixel coordinate, the principal point included, is
half a pixel larger there: ``cx_colmap = cx + 0.5``, ``cy_colmap = cy + 0.5`` (a centred principal point is
``(W / 2, H / 2)`` in COLMAP). Focal lengths are the same in both.

The model is a distortion-free pinhole: the distortion coefficients are zero.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = [
    "COLMAP_MODELS",
    "COLMAP_PIXEL_OFFSET",
    "OPENCV_DISTORTION",
    "colmap_camera", "kornia_camera", "opencv_camera", "pinhole_keys"]

#: the COLMAP camera models :func:`colmap_camera` writes, with their parameter names
COLMAP_MODELS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy")}
#: OpenCV's five distortion coefficients ``(k1, k2, p1, p2, k3)`` of a pinhole camera: all zero
OPENCV_DISTORTION = ("k1", "k2", "p1", "p2", "k3")
#: COLMAP's pixel origin minus ours, in pixels (its coordinates are larger by this much)
COLMAP_PIXEL_OFFSET = 0.5


def kornia_camera(K: Tensor, R: Tensor, image_size: Tensor):
    """A batched :class:`kornia.geometry.camera.PinholeCamera` of intrinsics ``K`` and rotation ``R``.

    The extrinsics are ``[R | 0]``: the camera sits at the world origin (a single image says nothing of where), and
    world directions are those of the Manhattan frame (world y down, see :class:`Calibration`).

    Args:
        K: (B, 3, 3) intrinsics, or (3, 3).
        R: (B, 3, 3) world-to-camera rotations, or (3, 3).
        image_size: (B, 2) ``(height, width)``, or (2,).

    Returns:
        a ``PinholeCamera`` of batch size B (1 for unbatched input) with (B, 4, 4) intrinsics and extrinsics and
        (B,) height and width, in K's dtype and device.
    """
    from kornia.geometry.camera import PinholeCamera

    K, R, image_size = (K[None], R[None], image_size[None]) if K.dim() == 2 else (K, R, image_size)
    batch = K.shape[0]
    intrinsics = torch.eye(4, dtype=K.dtype, device=K.device).repeat(batch, 1, 1)
    intrinsics[:, :3, :3] = K
    extrinsics = torch.eye(4, dtype=K.dtype, device=K.device).repeat(batch, 1, 1)
    extrinsics[:, :3, :3] = R.to(K.dtype)
    size = image_size.to(device=K.device, dtype=K.dtype)
    return PinholeCamera(intrinsics, extrinsics, size[:, 0].clone(), size[:, 1].clone())


def opencv_camera(K: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's camera matrix and distortion coefficients.

    Args:
        K: (3, 3) or (B, 3, 3) intrinsics.

    Returns:
        ``(K, dist)``: float64 numpy arrays of shape (3, 3) and (5,) (or (B, 3, 3) and (B, 5)); ``dist`` is
        zero, in OpenCV's order ``(k1, k2, p1, p2, k3)``.
    """
    matrix = K.detach().cpu().double().numpy().copy()
    return matrix, np.zeros((*matrix.shape[:-2], len(OPENCV_DISTORTION)))


def colmap_camera(K: Tensor, image_size: Tensor, model: str = "SIMPLE_PINHOLE", camera_id: int = 1) -> dict:
    """One COLMAP camera (as in ``cameras.txt``) of an unbatched calibration.

    Args:
        K: (3, 3) intrinsics in our pixels (origin at the centre of the top-left pixel).
        image_size: (2,) ``(height, width)``.
        model: ``"SIMPLE_PINHOLE"`` (one focal length; ours has square pixels) or ``"PINHOLE"`` (fx, fy).
        camera_id: COLMAP's camera id written first on the line.

    Returns:
        ``{"camera_id", "model", "width", "height", "params", "line"}``: ``params`` in the model's order
        (:data:`COLMAP_MODELS`), with ``cx``, ``cy`` shifted by +0.5 px to COLMAP's corner origin; ``line`` the
        ``cameras.txt`` line ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``.
    """
    if model not in COLMAP_MODELS:
        raise ValueError(f"unknown COLMAP model {model!r}; choose one of {', '.join(COLMAP_MODELS)}")
    k = K.detach().cpu().double()
    fx, fy = float(k[0, 0]), float(k[1, 1])
    cx, cy = float(k[0, 2]) + COLMAP_PIXEL_OFFSET, float(k[1, 2]) + COLMAP_PIXEL_OFFSET
    height, width = (int(v) for v in image_size.tolist())
    params = [(fx + fy) / 2, cx, cy] if model == "SIMPLE_PINHOLE" else [fx, fy, cx, cy]
    line = " ".join([str(camera_id), model, str(width), str(height), *(repr(p) for p in params)])
    return {"camera_id": camera_id, "model": model, "width": width, "height": height, "params": params, "line": line}


def pinhole_keys(K: Tensor) -> dict:
    """The JSON keys of the pinhole model beside ``K``: ``cx``, ``cy`` (our pixels) and zero ``distortion``
    (OpenCV's ``k1, k2, p1, p2, k3``)."""
    k = K.detach().cpu().double()
    return {"cx": float(k[0, 2]), "cy": float(k[1, 2]), "distortion": [0.0] * len(OPENCV_DISTORTION)}
