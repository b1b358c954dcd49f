r"""One-parameter radial lens distortion: the division model, its inverse, and OpenCV's polynomial closest to it.

The division model (Fitzgibbon 2001; GeoCalib's ``simple_divisional``, this package's renderer) maps a distorted
pixel ``p_d`` to the undistorted (pinhole) one ``p_u`` through the ray coordinates ``x = (p - c) / f`` about the
principal point ``c``:

.. math:: x_u = \frac{x_d}{1 + k_1 |x_d|^2}

``k1 < 0`` is barrel distortion (straight lines bow outwards, the undistorted image is larger), ``k1 > 0``
pincushion. Undistorting is the formula itself; distorting has a closed form too
(:func:`distort_points`), so neither needs iterations, where OpenCV's polynomial model needs them to undistort.

Ours: kornia's distortion (``kornia.geometry.calibration``) is OpenCV's polynomial model, which has no closed-form
inverse; :func:`opencv_radial` gives its coefficients for the tools that speak it.
"""

from __future__ import annotations

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from kornia.geometry.conversions import denormalize_points_with_intrinsics, normalize_points_with_intrinsics
from kornia.geometry.linalg import squared_norm
from torch import Tensor

__all__ = ["OPENCV_DISTORTION", "coefficient_from_pseudo", "coefficient_to_pseudo", "distort_points", "opencv_radial",
           "undistort_points"]

#: OpenCV's five distortion coefficients, in its order: radial ``k1, k2``, tangential ``p1, p2``, radial ``k3``
OPENCV_DISTORTION = ("k1", "k2", "p1", "p2", "k3")


def coefficient_from_pseudo(lam: Tensor, focal: Tensor, height: int, width: int) -> Tensor:
    """The division model's coefficient in focal-length units (the ray coordinates ``(p - c) / f`` of this module) of
    one in the pseudo camera's (``(p - c) / s``, ``s`` half the long side): ``k1 = lam (f / s)^2``. (B,) -> (B,).

    Example:
        >>> coefficient_from_pseudo(torch.tensor([-0.1]), torch.tensor([640.0]), 480, 640)
        tensor([-0.4000])
    """
    return lam * (focal / (max(height, width) / 2.0)).square()


def coefficient_to_pseudo(k1: Tensor, focal: Tensor, height: int, width: int) -> Tensor:
    """The inverse of :func:`coefficient_from_pseudo`: ``lam = k1 (s / f)^2``. (B,) -> (B,)."""
    return k1 * ((max(height, width) / 2.0) / focal).square()


def undistort_points(points: Tensor, K: Tensor, k1: Tensor) -> Tensor:
    """Undistorted pixels of distorted ones, ``x_u = x_d / (1 + k1 |x_d|^2)``.

    Args:
        points: (B, N, 2) pixels of the distorted image.
        K: (B, 3, 3) intrinsics (focal length and principal point; square pixels).
        k1: (B,) coefficients of the division model.

    Returns:
        (B, N, 2) pixels of the undistorted image. Beyond the model's reach (``1 + k1 |x_d|^2 <= 0``, far outside
        any photo of barrel distortion) the denominator is clamped to 1e-6: finite, very far out.

    Example:
        >>> K = torch.tensor([[[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]]])
        >>> undistort_points(torch.tensor([[[150.0, 50.0]]]), K, torch.tensor([-0.2]))  # x_d = 1 -> x_u = 1.25
        tensor([[[175.,  50.]]])
    """
    KORNIA_CHECK_SHAPE(points, ["B", "N", "2"])
    KORNIA_CHECK_SHAPE(K, ["B", "3", "3"])
    x = normalize_points_with_intrinsics(points, K)
    scale = 1.0 + k1.to(x)[:, None, None] * squared_norm(x, keepdim=True)
    return denormalize_points_with_intrinsics(x / scale.clamp_min(1e-6), K)


def distort_points(points: Tensor, K: Tensor, k1: Tensor) -> Tensor:
    """Distorted pixels of undistorted ones: the inverse of :func:`undistort_points`.

    With ``r_u = |x_u|``, ``x_u = x_d / (1 + k1 r_d^2)`` gives ``k1 r_u r_d^2 - r_d + r_u = 0``, whose root that
    goes to ``r_u`` as ``k1 -> 0`` is ``r_d = 2 r_u / (1 + sqrt(1 - 4 k1 r_u^2))``.

    Args:
        points: (B, N, 2) pixels of the undistorted image.
        K: (B, 3, 3) intrinsics; k1: (B,) coefficients.

    Returns:
        (B, N, 2) pixels of the distorted image. For ``k1 > 0`` an undistorted radius beyond ``1 / (2 sqrt(k1))``
        has no distorted point; it is taken to that largest radius (the square root's argument is clamped to 0).

    Example:
        >>> K = torch.tensor([[[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]]])
        >>> distort_points(torch.tensor([[[175.0, 50.0]]]), K, torch.tensor([-0.2]))
        tensor([[[150.,  50.]]])
    """
    KORNIA_CHECK_SHAPE(points, ["B", "N", "2"])
    KORNIA_CHECK_SHAPE(K, ["B", "3", "3"])
    x = normalize_points_with_intrinsics(points, K)
    r2 = squared_norm(x, keepdim=True)
    root = (1.0 - 4.0 * k1.to(x)[:, None, None] * r2).clamp_min(0.0).sqrt()
    return denormalize_points_with_intrinsics(x * (2.0 / (1.0 + root)), K)


def opencv_radial(
    k1: Tensor, K: Tensor, height: int, width: int, terms: int = 3, samples: int = 64
) -> Tensor:
    """OpenCV's radial coefficients ``(k1, k2, k3)`` (or the first ``terms`` of them) closest to the division model
    over an image.

    OpenCV distorts undistorted rays ``x_u`` as ``x_d = x_u (1 + k1 r_u^2 + k2 r_u^4 + k3 r_u^6)``; the division
    model gives ``x_d / x_u = 1 + k1 r_d^2``. The coefficients are the least-squares fit of the distorted radius at
    ``samples`` radii from the principal point to the image's farthest corner (for small ``k1``, OpenCV's
    ``k1`` is the division model's to first order). COLMAP's ``SIMPLE_RADIAL`` and ``RADIAL`` are the same
    polynomial with one and two terms.

    Args:
        k1: (B,) division-model coefficients; K: (B, 3, 3) intrinsics; height, width: the image's size.
        terms: 1, 2 or 3 coefficients.
        samples: radii of the fit.

    Returns:
        (B, terms) float64; zero where ``k1`` is zero.

    Example:
        >>> K = torch.tensor([[[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]])
        >>> [round(v, 2) for v in opencv_radial(torch.tensor([-0.1]), K, 480, 640)[0].tolist()]
        [-0.1, 0.02, -0.0]
    """
    K64, k = K.detach().double(), k1.detach().double()
    corners = torch.tensor([[0.0, 0.0], [float(width) - 1, 0.0], [0.0, float(height) - 1]], dtype=torch.float64)
    corners = torch.cat([corners, torch.tensor([[float(width) - 1, float(height) - 1]], dtype=torch.float64)])
    rays = normalize_points_with_intrinsics(corners.to(K64.device).expand(len(K64), 4, 2), K64)
    reach = torch.linalg.vector_norm(rays, dim=-1).amax(-1)  # (B,) the farthest corner, distorted rays
    r_d = reach[:, None] * torch.linspace(0.0, 1.0, samples + 1, dtype=torch.float64, device=K64.device)[1:]
    scale = 1.0 + k[:, None] * r_d.square()
    r_u = r_d / scale.clamp_min(1e-6)
    # the fit weighs each radius by r_u: its error is then the distorted radius's, in the rays' units
    design = torch.stack([r_u**3, r_u**5, r_u**7][:terms], -1)  # (B, S, terms)
    target = (r_d - r_u)[..., None]
    solution = torch.linalg.lstsq(design, target).solution[..., 0]
    return torch.where(k[:, None] == 0, torch.zeros_like(solution), solution)
