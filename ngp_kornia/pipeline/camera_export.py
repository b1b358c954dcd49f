"""A calibration as the camera types of the tools around it: kornia's ``PinholeCamera``, OpenCV's ``(K, dist)``
and COLMAP's ``SIMPLE_PINHOLE`` / ``PINHOLE`` cameras (the ``Calibration.to_*`` methods call these).

Pixel conventions: ours, kornia's and OpenCV's put the origin at the *centre* of the top-left pixel, so a centred
principal point is ``((W - 1) / 2, (H - 1) / 2)``. COLMAP puts the origin at the top-left *corner* of the image
(the centre of the top-left pixel is ``(0.5, 0.5)``), so every pixel coordinate, the principal point included, is
half a pixel larger there: ``cx_colmap = cx + 0.5``, ``cy_colmap = cy + 0.5`` (a centred principal point is
``(W / 2, H / 2)`` in COLMAP). Focal lengths are the same in both.

The model is a pinhole, distortion-free unless the calibration carries the division model's ``k1``
(:mod:`ngp_kornia.geometry.lens`): OpenCV and COLMAP then get the polynomial closest to it over the image
(:func:`~ngp_kornia.geometry.lens.opencv_radial`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry.lens import opencv_radial
from ngp_kornia.geometry.pinhole import Camera

__all__ = [
    "COLMAP_MODELS",
    "COLMAP_PIXEL_OFFSET",
    "OPENCV_DISTORTION",
    "PINHOLE_MODELS",
    "colmap_camera", "kornia_camera", "opencv_camera", "opencv_distortion", "pinhole_keys"]

#: the COLMAP camera models :func:`colmap_camera` writes, with their parameter names
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
}
#: the COLMAP models without distortion
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
#: OpenCV's five distortion coefficients, in its order (all zero for a distortion-free pinhole)
OPENCV_DISTORTION = ("k1", "k2", "p1", "p2", "k3")
#: COLMAP's pixel origin minus ours, in pixels (its coordinates are larger by this much)
COLMAP_PIXEL_OFFSET = 0.5


def kornia_camera(K: Tensor, R: Tensor, image_size: Tensor):
    """A batched :class:`kornia.geometry.camera.PinholeCamera` of intrinsics ``K`` and rotation ``R``
    (:meth:`~ngp_kornia.geometry.pinhole.Camera.to_kornia`).

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
    return Camera.from_matrix(K, R.to(K), image_size).to_kornia()


def opencv_distortion(K: Tensor, k1: Tensor | None = None, image_size: Tensor | None = None) -> np.ndarray:
    """OpenCV's ``(k1, k2, p1, p2, k3)`` (5,) or (B, 5) float64: zero without ``k1``, else the radial polynomial
    closest to the division model over the image (``image_size``, (2,) or (B, 2) ``(height, width)``, needed then).
    """
    if k1 is None:
        return np.zeros((*K.shape[:-2], len(OPENCV_DISTORTION)))
    batched = K.dim() == 3
    K3, k, size = (K, k1, image_size) if batched else (K[None], k1[None], image_size[None])
    radial = opencv_radial(k, K3, *(int(v) for v in size[0].tolist()))  # a batch shares one image size
    zero = torch.zeros_like(radial[:, 0])
    dist = torch.stack([radial[:, 0], radial[:, 1], zero, zero, radial[:, 2]], -1).cpu().numpy()
    return dist if batched else dist[0]


def opencv_camera(
    K: Tensor, k1: Tensor | None = None, image_size: Tensor | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's camera matrix and distortion coefficients.

    Args:
        K: (3, 3) or (B, 3, 3) intrinsics.
        k1: () or (B,) the division model's coefficient, None for a distortion-free pinhole.
        image_size: () or (B, 2) ``(height, width)``, used with ``k1``.

    Returns:
        ``(K, dist)``: float64 numpy arrays of shape (3, 3) and (5,) (or (B, 3, 3) and (B, 5)); ``dist`` in
        OpenCV's order ``(k1, k2, p1, p2, k3)`` (:func:`opencv_distortion`).
    """
    matrix = K.detach().cpu().double().numpy().copy()
    return matrix, opencv_distortion(K, k1, image_size)


def colmap_camera(
    K: Tensor, image_size: Tensor, model: str | None = None, camera_id: int = 1, k1: Tensor | None = None
) -> dict:
    """One COLMAP camera (as in ``cameras.txt``) of an unbatched calibration.

    Args:
        K: (3, 3) intrinsics in our pixels (origin at the centre of the top-left pixel).
        image_size: (2,) ``(height, width)``.
        model: ``"SIMPLE_PINHOLE"`` (one focal length; ours has square pixels), ``"PINHOLE"`` (fx, fy),
            ``"SIMPLE_RADIAL"`` or ``"RADIAL"`` (with one or two radial terms closest to ``k1``); None:
            ``SIMPLE_PINHOLE`` without ``k1``, ``RADIAL`` with it.
        camera_id: COLMAP's camera id written first on the line.
        k1: () the division model's coefficient, None for a distortion-free pinhole.

    Raises:
        ValueError: an unknown model, or a pinhole model for a calibration with ``k1`` (it would drop the
            distortion).

    Returns:
        ``{"camera_id", "model", "width", "height", "params", "line"}``: ``params`` in the model's order
        (:data:`COLMAP_MODELS`), with ``cx``, ``cy`` shifted by +0.5 px to COLMAP's corner origin; ``line`` the
        ``cameras.txt`` line ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``.
    """
    model = model or ("SIMPLE_PINHOLE" if k1 is None else "RADIAL")
    if model not in COLMAP_MODELS:
        raise ValueError(f"unknown COLMAP model {model!r}; choose one of {', '.join(COLMAP_MODELS)}")
    if k1 is not None and model in PINHOLE_MODELS:
        raise ValueError(f"this calibration has lens distortion (k1); {model} would drop it: use RADIAL or "
                         "SIMPLE_RADIAL")
    k = K.detach().cpu().double()
    fx, fy = float(k[0, 0]), float(k[1, 1])
    cx, cy = float(k[0, 2]) + COLMAP_PIXEL_OFFSET, float(k[1, 2]) + COLMAP_PIXEL_OFFSET
    height, width = (int(v) for v in image_size.tolist())
    params = [fx, fy, cx, cy] if model == "PINHOLE" else [(fx + fy) / 2, cx, cy]
    if model not in PINHOLE_MODELS:
        terms = len(COLMAP_MODELS[model]) - 3
        coefficient = torch.zeros(1, dtype=torch.float64) if k1 is None else k1.detach().cpu().double().reshape(1)
        params += opencv_radial(coefficient, k[None], height, width, terms)[0].tolist()
    line = " ".join([str(camera_id), model, str(width), str(height), *(repr(p) for p in params)])
    return {"camera_id": camera_id, "model": model, "width": width, "height": height, "params": params, "line": line}


def pinhole_keys(K: Tensor, k1: Tensor | None = None, image_size: Tensor | None = None) -> dict:
    """The JSON keys of the camera model beside ``K`` (unbatched): ``cx``, ``cy`` (our pixels) and ``distortion``,
    OpenCV's ``k1, k2, p1, p2, k3`` (:func:`opencv_distortion`: zero for a distortion-free pinhole)."""
    k = K.detach().cpu().double()
    distortion = opencv_distortion(K.detach().cpu(), None if k1 is None else k1.detach().cpu(), image_size)
    return {"cx": float(k[0, 2]), "cy": float(k[1, 2]), "distortion": [float(v) for v in distortion]}
