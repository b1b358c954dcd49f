r"""Rectifying homographies from a calibration: level the horizon, make verticals vertical, face a facade.

Every homography here is the image of a pure rotation of the camera about its centre, ``H = K Q K^-1``, where
``Q`` maps old camera directions to the directions of a virtual camera with the same intrinsics. The conventions
are those of :mod:`ngp_kornia.geometry.camera`: pixels x right, y down, origin at the centre of the top-left
pixel; camera frame x right, y down, z forward; ``R`` world-to-camera with world y pointing down; the up vector is
``-R[:, 1]``.

:func:`rectify` applies such a homography to a batch of images with
:func:`kornia.geometry.transform.warp_perspective`, choosing the output size and translation so that either all
input pixels are kept (``crop="keep"``) or only valid pixels are (``crop="valid"``). The homographies themselves
are ours: kornia has no rectification from a calibration.
"""

from __future__ import annotations

import math

import torch
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from kornia.geometry import create_meshgrid
from kornia.geometry.conversions import convert_points_to_homogeneous
from kornia.geometry.transform import remap, warp_perspective
from torch import Tensor

from ngp_kornia.geometry.camera import image_center
from ngp_kornia.geometry.pinhole import Camera

__all__ = ["frontal_homography", "level_homography", "rectify", "upright_homography"]

#: ``crop="keep"`` refuses outputs larger than this many times the input area (when ``size`` is not given).
MAX_AREA_RATIO = 4.0


def _tiny(x: Tensor) -> float:
    return float(torch.finfo(x.dtype).tiny) ** 0.5


def _check_camera(K: Tensor, R: Tensor) -> None:
    KORNIA_CHECK_SHAPE(K, ["B", "3", "3"])
    KORNIA_CHECK_SHAPE(R, ["B", "3", "3"])
    KORNIA_CHECK(K.shape[0] == R.shape[0], f"K and R must have the same batch size, got {K.shape[0]} and {R.shape[0]}")


def _conjugate(K: Tensor, Q: Tensor) -> Tensor:
    """``K @ Q @ K^-1``: the homography of the camera rotation ``Q``."""
    return K @ Q @ torch.linalg.inv(K)


def _unroll(up: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Cosine and sine of the roll and the norm of the up vector's image-plane part, without atan2 (smooth)."""
    n = torch.sqrt(up[:, 0] ** 2 + up[:, 1] ** 2 + _tiny(up))
    return -up[:, 1] / n, up[:, 0] / n, n


def _level_rotation(R: Tensor) -> Tensor:
    """``R_z(-roll)`` from the up vector ``-R[:, 1]``: from its cosine and sine, where kornia's rotations take an
    angle (an atan2 of the up vector, not smooth where its image-plane part vanishes)."""
    up = -R[:, :, 1]
    c, s, _ = _unroll(up)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([c, s, z, -s, c, z, z, z, o], -1).reshape(-1, 3, 3)


def level_homography(K: Tensor, R: Tensor) -> Tensor:
    r"""Homography that removes the roll only: the camera turns about its optical axis by ``-roll``.

    ``H = K R_z(-roll) K^-1`` with the roll read from the up vector ``-R[:, 1]``; after it the horizon is
    horizontal and the pitch and yaw are unchanged.

    Args:
        K: (B, 3, 3) intrinsics.
        R: (B, 3, 3) world-to-camera rotation.

    Returns:
        (B, 3, 3) homography from input pixels to levelled pixels.

    Example:
        >>> from ngp_kornia.geometry.camera import intrinsics_matrix, rotation_from_angles
        >>> K = intrinsics_matrix(torch.tensor([500.0]), torch.tensor([319.5, 239.5]))
        >>> R = rotation_from_angles(torch.tensor([10.0]), torch.tensor([0.0]))
        >>> torch.allclose(level_homography(K, R), torch.eye(3)[None], atol=1e-3)
        True
    """
    _check_camera(K, R)
    return _conjugate(K, _level_rotation(R).to(K))


def upright_homography(K: Tensor, R: Tensor) -> Tensor:
    r"""Homography that removes roll and pitch: verticals become vertical and the horizon level.

    ``H = K Q K^-1`` with ``Q = R_x(pitch) R_z(-roll)``, the rotation that turns the camera's up vector into
    ``(0, -1, 0)`` while keeping the yaw (``Q R = R_y(-yaw)``). Computed from the up vector, without angles.

    Args:
        K: (B, 3, 3) intrinsics.
        R: (B, 3, 3) world-to-camera rotation.

    Returns:
        (B, 3, 3) homography from input pixels to upright pixels.

    Example:
        >>> from ngp_kornia.geometry.camera import intrinsics_matrix
        >>> K = intrinsics_matrix(torch.tensor([500.0]), torch.tensor([319.5, 239.5]))
        >>> H = upright_homography(K, torch.eye(3)[None])
        >>> torch.allclose(H, torch.eye(3)[None], atol=1e-3)
        True
    """
    _check_camera(K, R)
    up = -R[:, :, 1]
    up = up / up.norm(dim=-1, keepdim=True).clamp_min(_tiny(up))
    _, _, cp = _unroll(up)  # cos(pitch) = |up_xy|, sin(pitch) = up_z
    sp = up[:, 2]
    z, o = torch.zeros_like(cp), torch.ones_like(cp)
    rx = torch.stack([o, z, z, z, cp, -sp, z, sp, cp], -1).reshape(-1, 3, 3)
    return _conjugate(K, (rx @ _level_rotation(R)).to(K))


def frontal_homography(K: Tensor, R: Tensor, axis: int = 2) -> Tensor:
    r"""Perspective control facing one facade of the Manhattan frame.

    The virtual camera looks along the horizontal world axis ``axis`` (``0`` = x, ``2`` = z), with the sign that is
    closest to the current optical axis (so it faces the camera), its y axis along the world down direction
    (verticals stay vertical) and its x axis completing a right-handed frame. The facade perpendicular to ``axis``
    is then seen front-on: its horizontal VP goes to infinity along the image x direction and the VP of ``axis``
    to the principal point.

    Args:
        K: (B, 3, 3) intrinsics.
        R: (B, 3, 3) world-to-camera rotation.
        axis: ``0`` or ``2``, the world axis the virtual camera looks along.

    Returns:
        (B, 3, 3) homography from input pixels to frontal pixels.

    Example:
        >>> from ngp_kornia.geometry.camera import intrinsics_matrix
        >>> K = intrinsics_matrix(torch.tensor([500.0]), torch.tensor([319.5, 239.5]))
        >>> H = frontal_homography(K, torch.eye(3)[None], axis=2)
        >>> torch.allclose(H, torch.eye(3)[None], atol=1e-3)
        True
    """
    _check_camera(K, R)
    KORNIA_CHECK(axis in (0, 2), f"axis must be 0 (world x) or 2 (world z), got {axis!r}")
    B = R.shape[0]
    eye = torch.eye(3, dtype=R.dtype, device=R.device)
    sign = torch.where(R[:, 2, axis] < 0, -1.0, 1.0).to(R)  # world axis i seen from the camera is R[:, :, i]
    forward = sign[:, None] * eye[axis].expand(B, 3)
    down = eye[1].expand(B, 3)
    right = torch.linalg.cross(down, forward)
    R_new = torch.stack([right, down, forward], -2)  # rows: the virtual camera's axes in world coordinates
    return _conjugate(K, (R_new @ R.transpose(-1, -2)).to(K))


def _project(Hm: Tensor, pts: Tensor) -> tuple[Tensor, Tensor]:
    """Points (B, N, 2) through (B, 3, 3): Euclidean points (B, N, 2) and the homogeneous scale (B, N).

    Not kornia's ``transform_points``: that leaves a point with ``|w| <= 1e-8`` undivided (OpenCV's rule) and drops
    ``w``, which tells the boxes below that a corner went past the horizon.
    """
    ph = convert_points_to_homogeneous(pts) @ Hm.transpose(-1, -2)
    w = ph[..., 2]
    return ph[..., :2] / torch.where(w.abs() < _tiny(w), torch.full_like(w, _tiny(w)), w)[..., None], w


def _corners(height: int, width: int, inset: float, like: Tensor) -> Tensor:
    lo_x, hi_x, lo_y, hi_y = -0.5 + inset, width - 0.5 - inset, -0.5 + inset, height - 0.5 - inset
    return torch.tensor([[lo_x, lo_y], [hi_x, lo_y], [hi_x, hi_y], [lo_x, hi_y]], dtype=like.dtype, device=like.device)


#: points per side of the border of a distorted image, whose undistorted border is curved
BORDER_POINTS = 64


def _border(height: int, width: int, inset: float, Hm: Tensor, lens: Camera | None) -> Tensor:
    """The image's border (B, P, 2) in order around it: its four corners, or, for a distorted image (``lens``: its
    batched camera), :data:`BORDER_POINTS` points per side, undistorted."""
    corners = _corners(height, width, inset, Hm)
    if lens is None:
        return corners.expand(Hm.shape[0], 4, 2)
    t = torch.arange(BORDER_POINTS, dtype=Hm.dtype, device=Hm.device)[:, None] / BORDER_POINTS
    sides = [corners[i] + t * (corners[(i + 1) % 4] - corners[i]) for i in range(4)]
    return lens.undistort(torch.cat(sides).expand(Hm.shape[0], -1, 2))


def _keep_box(Hm: Tensor, height: int, width: int, lens=None) -> tuple[Tensor, Tensor]:
    """Centre (B, 2) and size (B, 2) ``(w, h)`` of the bounding box of the warped image."""
    pts, w = _project(Hm, _border(height, width, 0.0, Hm, lens))
    if bool((w <= 0).any()):
        raise ValueError("the homography sends part of the image to infinity; it cannot be rectified in full")
    lo, hi = pts.min(dim=1).values, pts.max(dim=1).values
    return (lo + hi) / 2, hi - lo


def _valid_box(Hm: Tensor, height: int, width: int, lens=None) -> tuple[Tensor, Tensor]:
    """Centre (B, 2) and size (B, 2) of a large rectangle with the input's aspect inside the warped image.

    The rectangle is centred on the mean of the warped corners and scaled up until it touches an edge of the warped
    quadrilateral (exact for that centre; the centre itself is the approximation). The quadrilateral spans the input's
    outermost pixel centres, so bilinear sampling never reads the zero padding. A distorted image's border is curved
    (its sides bow in or out): it is sampled densely and the rectangle grows until it meets the first border point.
    """
    pts, w = _project(Hm, _border(height, width, 0.5, Hm, lens))
    if bool((w <= 0).any()):
        raise ValueError("the homography sends part of the image to infinity; it cannot be rectified")
    centre = pts.mean(dim=1)
    half = torch.tensor([width / 2.0, height / 2.0], dtype=Hm.dtype, device=Hm.device)
    if lens is not None:  # the scale at which the rectangle reaches each border point; the least of them
        scale = ((pts - centre[:, None]).abs() / half).amax(-1).min(dim=1).values
        return centre, scale[:, None] * 2 * half
    a, b = pts, pts.roll(-1, dims=1)
    normal = torch.stack([-(b - a)[..., 1], (b - a)[..., 0]], -1)  # edge normals, inward up to a common sign
    dist = ((centre[:, None] - a) * normal).sum(-1)
    orient = torch.where(dist.sum(-1, keepdim=True) < 0, -1.0, 1.0).to(dist)
    dist, normal = dist * orient, normal * orient[..., None]
    reach = (normal.abs() * half).sum(-1)  # how far a corner of the unit-scale rectangle goes along each normal
    scale = (dist / reach.clamp_min(_tiny(reach))).min(dim=1).values
    if bool((scale <= 0).any()):
        raise ValueError("the warped image contains no valid rectangle")
    return centre, scale[:, None] * 2 * half


def rectify(
    images: Tensor, H: Tensor, size: tuple[int, int] | None = None, crop: str = "keep", camera: Camera | None = None
) -> tuple[Tensor, Tensor]:
    r"""Warp images with a rectifying homography, choosing the output frame.

    ``crop="keep"``: the output frame is the bounding box of the warped image, so no input pixel is lost.

    ``crop="valid"``: the output frame is a rectangle with the input's aspect ratio containing only valid (warped)
    pixels: it is centred on the mean of the warped corners and made as large as fits inside the warped image (an
    approximation of the largest such rectangle; exact for that centre).

    For a batch the output size is the largest box (``keep``) or the smallest rectangle (``valid``), each image centred
    on its own box. With ``size`` the chosen frame is scaled uniformly to fit into ``size`` and centred; without it
    the output may not exceed ``4x`` the input area, to stay sane for extreme homographies.

    With ``camera``, the images' batched :class:`~ngp_kornia.geometry.pinhole.Camera` (a calibration's ``camera``),
    a lens with a distortion (:mod:`ngp_kornia.geometry.lens`) is undone on the way: ``H`` maps the undistorted
    image's pixels (as a calibration's ``K`` and ``R`` give it), and the frame fits its curved border.

    Args:
        images: (B, C, H, W) floating-point images.
        H: (B, 3, 3) homographies from input pixels to rectified pixels (e.g. :func:`upright_homography`).
        size: output ``(height, width)``; derived from the frame when None.
        crop: ``"keep"`` or ``"valid"``.
        camera: the images' cameras (batch B), or None for pinhole images.

    Returns:
        The warped images (B, C, h, w) and the (B, 3, 3) homography actually applied (``H`` followed by the
        output's scale and translation), from input (with a distortion: undistorted input) pixels to output pixels.

    Raises:
        ValueError: a bad ``crop`` or ``size``; a homography sending part of the image to infinity; an output above
            ``4x`` the input area when ``size`` is None.

    Example:
        >>> out, applied = rectify(torch.rand(2, 3, 24, 32), torch.eye(3).repeat(2, 1, 1))
        >>> tuple(out.shape), torch.allclose(applied, torch.eye(3))
        ((2, 3, 24, 32), True)
    """
    KORNIA_CHECK_SHAPE(images, ["B", "C", "H", "W"])
    KORNIA_CHECK_SHAPE(H, ["B", "3", "3"])
    KORNIA_CHECK(images.is_floating_point(), f"images must be floating point, got {images.dtype}")
    KORNIA_CHECK(H.shape[0] == images.shape[0], f"got {images.shape[0]} images but {H.shape[0]} homographies")
    if crop not in ("keep", "valid"):
        raise ValueError(f"crop must be 'keep' or 'valid', got {crop!r}")
    if size is not None and (len(size) != 2 or min(int(s) for s in size) < 1):
        raise ValueError(f"size must be (height, width) with positive entries, got {size!r}")
    if camera is not None and (not camera.batched or len(camera) != H.shape[0]):
        raise ValueError(f"rectify() takes the cameras of the {H.shape[0]} images as one batched Camera "
                         "(cal.camera of a batch; for one image, cal.camera.apply(lambda t: t[None]))")
    height, width = images.shape[-2:]
    Hm = H.to(images)
    Hm = Hm / Hm[:, 2:, 2:].where(Hm[:, 2:, 2:].abs() > _tiny(Hm), torch.ones_like(Hm[:, 2:, 2:]))
    lens = camera if camera is not None and camera.distorted else None
    frame, out_h, out_w = _output_frame(Hm, height, width, crop, size, lens)
    applied = frame @ Hm
    if lens is None:
        return warp_perspective(images, applied, (out_h, out_w), align_corners=True), applied
    return _undistorting_warp(images, applied, (out_h, out_w), lens), applied


def _undistorting_warp(images: Tensor, applied: Tensor, size: tuple[int, int], lens: Camera) -> Tensor:
    """The images sampled at every output pixel taken back through ``applied`` and distorted (bilinear, zeros
    outside)."""
    B, (out_h, out_w) = images.shape[0], size
    grid = create_meshgrid(out_h, out_w, False, images.device, images.dtype).reshape(1, -1, 2).expand(B, -1, 2)
    back, _ = _project(torch.linalg.inv(applied), grid)
    source = lens.distort(back).reshape(B, out_h, out_w, 2)
    return remap(images, source[..., 0], source[..., 1], align_corners=True)


def _output_frame(
    Hm: Tensor, height: int, width: int, crop: str, size: tuple[int, int] | None, lens=None
) -> tuple[Tensor, int, int]:
    """The output frame of :func:`rectify`: the (B, 3, 3) scale and translation from rectified pixels to output
    pixels, and the output's height and width."""
    if crop == "keep":
        centre, box = _keep_box(Hm, height, width, lens)
        extent = box.detach().max(dim=0).values
        out_w, out_h = (max(1, math.ceil(float(v) - 1e-6)) for v in extent)
    else:
        centre, box = _valid_box(Hm, height, width, lens)
        extent = box.detach().min(dim=0).values
        out_w, out_h = (max(1, math.floor(float(v) + 1e-6)) for v in extent)
    if size is None and out_w * out_h > MAX_AREA_RATIO * height * width:
        raise ValueError(
            f"the rectified image would be {out_w * out_h / (height * width):.1f}x the input area (limit "
            f"{MAX_AREA_RATIO:g}x); the homography is too extreme: crop='valid' (CLI: --crop valid) keeps the valid "
            "centre, size= sets the output size"
        )
    if size is None:
        scale = torch.ones_like(centre[:, 0])
    else:
        out_h, out_w = int(size[0]), int(size[1])
        scale = torch.minimum(out_w / box[:, 0], out_h / box[:, 1])
    z, o = torch.zeros_like(scale), torch.ones_like(scale)
    middle = image_center(out_h, out_w, like=scale)
    tx = middle[0] - scale * centre[:, 0]
    ty = middle[1] - scale * centre[:, 1]
    frame = torch.stack([scale, z, tx, z, scale, ty, z, z, o], -1).reshape(-1, 3, 3)
    return frame, out_h, out_w
