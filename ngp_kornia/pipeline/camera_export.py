"""A calibration as the camera types of the tools around it: kornia's ``PinholeCamera``, OpenCV's ``(K, dist)``
and COLMAP's ``SIMPLE_PINHOLE`` / ``PINHOLE`` cameras (the ``Calibration.to_*`` methods call these).

Pixel conventions: ours, kornia's and OpenCV's put the origin at the *centre* of the top-left pixel, so a centred
principal point is ``((W - 1) / 2, (H - 1) / 2)``. COLMAP puts the origin at the top-left *corner* of the image
(the centre of the top-left pixel is ``(0.5, 0.5)``), so every pixel coordinate, the principal point included, is
half a pixel larger there: ``cx_colmap = cx + 0.5``, ``cy_colmap = cy + 0.5`` (a centred principal point is
``(W / 2, H / 2)`` in COLMAP). Focal lengths are the same in both.

The model is a pinhole, distortion-free unless the camera carries a lens distortion (the division model of
:mod:`ngp_kornia.geometry.lens`): OpenCV and COLMAP then get the polynomial closest to it over the image
(:meth:`~ngp_kornia.geometry.pinhole.Camera.radial_polynomial`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry.lens import OPENCV_DISTORTION
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
    "RADIAL": ("f", "cx", "cy", *OPENCV_DISTORTION[:2]),  # OpenCV's first two radial terms
}
#: the COLMAP models without distortion
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
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


def opencv_distortion(camera: Camera) -> np.ndarray:
    """OpenCV's distortion coefficients (:data:`~ngp_kornia.geometry.lens.OPENCV_DISTORTION`) of a camera, (5,) or
    (B, 5) float64: zero for a distortion-free pinhole, else the radial polynomial closest to the lens over the image.
    """
    radial = camera.radial_polynomial().cpu()
    zero = torch.zeros_like(radial[..., 0])
    return torch.stack([radial[..., 0], radial[..., 1], zero, zero, radial[..., 2]], -1).numpy()


def opencv_camera(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's camera matrix and distortion coefficients.

    Args:
        camera: one camera or a batch (:class:`~ngp_kornia.geometry.pinhole.Camera`).

    Returns:
        ``(K, dist)``: float64 numpy arrays of shape (3, 3) and (5,) (or (B, 3, 3) and (B, 5)); ``dist`` in
        OpenCV's order (:func:`opencv_distortion`).
    """
    matrix = camera.K.detach().cpu().double().numpy().copy()
    return matrix, opencv_distortion(camera)


def colmap_camera(camera: Camera, model: str | None = None, camera_id: int = 1) -> dict:
    """One COLMAP camera (as in ``cameras.txt``) of an unbatched camera.

    Args:
        camera: the camera (:class:`~ngp_kornia.geometry.pinhole.Camera`), in our pixels (origin at the centre of the
            top-left pixel).
        model: ``"SIMPLE_PINHOLE"`` (one focal length; ours has square pixels), ``"PINHOLE"`` (fx, fy),
            ``"SIMPLE_RADIAL"`` or ``"RADIAL"`` (with one or two radial terms closest to the lens); None:
            ``SIMPLE_PINHOLE`` for a distortion-free camera, ``RADIAL`` for one with a lens distortion.
        camera_id: COLMAP's camera id written first on the line.

    Raises:
        ValueError: an unknown model, or a pinhole model for a camera with lens distortion (it would drop the
            distortion).

    Returns:
        ``{"camera_id", "model", "width", "height", "params", "line"}``: ``params`` in the model's order
        (:data:`COLMAP_MODELS`), with ``cx``, ``cy`` shifted by +0.5 px to COLMAP's corner origin; ``line`` the
        ``cameras.txt`` line ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``.
    """
    model = model or ("RADIAL" if camera.distorted else "SIMPLE_PINHOLE")
    if model not in COLMAP_MODELS:
        raise ValueError(f"unknown COLMAP model {model!r}; choose one of {', '.join(COLMAP_MODELS)}")
    if camera.distorted and model in PINHOLE_MODELS:
        raise ValueError(f"this calibration has lens distortion; {model} would drop it: use RADIAL or "
                         "SIMPLE_RADIAL")
    k = camera.K.detach().cpu().double()
    fx, fy = float(k[0, 0]), float(k[1, 1])
    cx, cy = float(k[0, 2]) + COLMAP_PIXEL_OFFSET, float(k[1, 2]) + COLMAP_PIXEL_OFFSET
    height, width = (int(v) for v in camera.image_size.tolist())
    params = [fx, fy, cx, cy] if model == "PINHOLE" else [(fx + fy) / 2, cx, cy]
    if model not in PINHOLE_MODELS:
        params += camera.radial_polynomial(len(COLMAP_MODELS[model]) - 3).tolist()
    line = " ".join([str(camera_id), model, str(width), str(height), *(repr(p) for p in params)])
    return {"camera_id": camera_id, "model": model, "width": width, "height": height, "params": params, "line": line}


def pinhole_keys(camera: Camera) -> dict:
    """The JSON keys of the camera model beside ``K`` (unbatched): ``cx``, ``cy`` (our pixels) and ``distortion``,
    OpenCV's coefficients (:func:`opencv_distortion`: zero for a distortion-free pinhole)."""
    k = camera.K.detach().cpu().double()
    distortion = opencv_distortion(camera)
    return {"cx": float(k[0, 2]), "cy": float(k[1, 2]), "distortion": [float(v) for v in distortion]}
