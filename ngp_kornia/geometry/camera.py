r"""Pinhole camera geometry: intrinsics, rotations, pitch / roll / yaw, field of view, horizon and zenith.

Conventions (pinned by ``tests/geometry/test_camera.py::test_convention_*``):

* Pixels: x right, y down, origin at the centre of the top-left pixel. An image of width ``W`` spans
  ``x in [-0.5, W - 0.5]``; its centre is ``((W - 1) / 2, (H - 1) / 2)``.
* Camera frame (OpenCV): x right, y down, z forward. ``K`` maps camera directions to homogeneous pixels.
* World frame: x and z horizontal, y pointing **down** (gravity), so the world up direction is ``(0, -1, 0)``.
  ``R`` maps world directions to camera directions, ``d_cam = R @ d_world``; its columns are the world axes seen
  from the camera, so ``K @ R[:, i]`` is the vanishing point of world axis ``i``.
* ``R = R_z(roll) @ R_x(-pitch) @ R_y(-yaw)``.
* pitch > 0: the camera looks up, the horizon lies below the image centre.
* roll > 0: the scene's up direction leans to the right in the image (the camera was turned counter-clockwise
  about its optical axis); the horizon then falls from left to right.
* yaw > 0: the camera is turned to the right of the world z axis.
* The up vector is ``up = -R[:, 1]``; ``pitch = asin(up_z)`` and ``roll = atan2(up_x, -up_y)``.
* Lines are homogeneous ``(a, b, c)`` with ``a x + b y + c = 0``. Horizons are returned with ``a^2 + b^2 = 1``
  and ``b >= 0``. The zenith is the vanishing point of the vertical, ``K @ up`` up to scale.

Angles are in degrees in every public function.
"""

from __future__ import annotations

import torch
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from kornia.geometry.liegroup import So3
from kornia.geometry.linalg import batched_dot_product
from kornia.image import ImageSize
from kornia.sensors.camera import PinholeModel
from torch import Tensor

__all__ = [
    "angles_from_rotation",
    "axis_rotations",
    "canonical_manhattan_rotation",
    "focal_from_fov",
    "focal_from_orthogonal_vps",
    "fov_from_focal",
    "horizon_border_points",
    "horizon_from_zenith",
    "image_center",
    "intrinsics_matrix",
    "normalize",
    "pinhole_model",
    "pitch_roll_from_up",
    "rotation_from_angles",
    "rotation_from_up",
    "rotation_from_vps",
    "up_from_rotation",
    "up_from_zenith",
    "vanishing_points_from_rotation",
    "zenith_from_horizon",
    "zenith_from_up",
]


def _eps(x: Tensor) -> float:
    return float(torch.finfo(x.dtype).eps) if x.is_floating_point() else 1e-12


def normalize(v: Tensor, dim: int = -1) -> Tensor:
    """Unit vectors along ``dim``; a zero vector stays zero instead of becoming NaN. The package's one normaliser.

    Ours: kornia keeps its normalisation private; ``torch.nn.functional.normalize`` with the dtype's eps gives the
    same values with more overhead a call, and this runs in the parser's hot path.

    Example:
        >>> normalize(torch.tensor([[3.0, 4.0], [0.0, 0.0]]))
        tensor([[0.6000, 0.8000],
                [0.0000, 0.0000]])
    """
    return v / torch.linalg.vector_norm(v, dim=dim, keepdim=True).clamp_min(_eps(v))


def image_center(height: int, width: int, like: Tensor | None = None) -> Tensor:
    """The image centre ``((W - 1) / 2, (H - 1) / 2)`` in the pixel-centre convention, shape (2,). The package's one
    image-centre formula.

    Ours: kornia has no image-centre helper of its own.

    Example:
        >>> image_center(480, 640)
        tensor([319.5000, 239.5000])
    """
    kw = {} if like is None else {"device": like.device, "dtype": like.dtype}
    return torch.tensor([(width - 1) / 2.0, (height - 1) / 2.0], **kw)


#: the image size handed to kornia's ``PinholeModel`` where only its matrix is wanted (``K`` does not depend on it)
_ANY_SIZE = ImageSize(1, 1)


def intrinsics_matrix(focal: Tensor, center: Tensor) -> Tensor:
    """Pinhole intrinsics with square pixels and no skew: kornia's ``PinholeModel`` matrix, the package's one
    ``K`` builder.

    Args:
        focal: (B,) focal length in pixels.
        center: (B, 2) or (2,) the principal point ``(c_x, c_y)`` in pixels.

    Returns:
        (B, 3, 3) matrices ``[[f, 0, c_x], [0, f, c_y], [0, 0, 1]]``.

    Example:
        >>> intrinsics_matrix(torch.tensor([500.0]), torch.tensor([319.5, 239.5]))
        tensor([[[500.0000,   0.0000, 319.5000],
                 [  0.0000, 500.0000, 239.5000],
                 [  0.0000,   0.0000,   1.0000]]])
    """
    KORNIA_CHECK_SHAPE(focal, ["B"])
    pp = center.to(focal).expand(focal.shape[0], 2)
    return pinhole_model(torch.stack([focal, focal, pp[:, 0], pp[:, 1]], -1)).matrix()


def pinhole_model(params: Tensor, image_size: ImageSize | None = None) -> PinholeModel:
    """kornia's :class:`~kornia.sensors.camera.PinholeModel` of parameters ``(f_x, f_y, c_x, c_y)`` (..., 4); its
    ``matrix()`` is ``K``. ``image_size``: kornia's ``ImageSize``, any when only ``K`` is wanted.

    Example:
        >>> pinhole_model(torch.tensor([500.0, 500.0, 319.5, 239.5])).matrix()[0]
        tensor([500.0000,   0.0000, 319.5000])
    """
    KORNIA_CHECK_SHAPE(params, ["*", "4"])
    return PinholeModel(_ANY_SIZE if image_size is None else image_size, params)


def fov_from_focal(focal: Tensor, size: float | Tensor) -> Tensor:
    """Field of view in degrees spanned by ``size`` pixels at focal length ``focal`` (both in pixels).

    Ours: kornia has no field-of-view conversion.

    Example:
        >>> fov_from_focal(torch.tensor([320.0]), 640)
        tensor([90.])
    """
    return torch.rad2deg(2.0 * torch.atan(torch.as_tensor(size).to(focal) / (2.0 * focal)))


def focal_from_fov(fov_deg: Tensor, size: float | Tensor) -> Tensor:
    """Focal length in pixels for a field of view (degrees) spanning ``size`` pixels; inverse of
    :func:`fov_from_focal`.

    Example:
        >>> focal_from_fov(torch.tensor([90.0]), 640)
        tensor([320.0000])
    """
    KORNIA_CHECK(bool(((fov_deg > 0) & (fov_deg < 180)).all()), "fov_deg must lie in (0, 180) degrees")
    return torch.as_tensor(size).to(fov_deg) / (2.0 * torch.tan(torch.deg2rad(fov_deg) / 2.0))


def axis_rotations(*factors: tuple[int, Tensor]) -> So3:
    """The product, left to right, of right-handed rotations about the camera axes, as kornia's
    :class:`~kornia.geometry.liegroup.So3`: ``(axis, degrees)`` pairs, axis 0 = x, 1 = y, 2 = z, the angles all of one
    shape ``(...)`` (``So3.rot_x`` / ``rot_y`` / ``rot_z``); ``.matrix()`` gives the (..., 3, 3) matrix.

    Example:
        >>> axis_rotations((2, torch.tensor(90.0))).matrix().round(decimals=6) + 0.0  # x turns towards y
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    turns = (So3.rot_x, So3.rot_y, So3.rot_z)
    product = None
    for axis, angle in factors:
        rotation = turns[axis](torch.deg2rad(angle))
        product = rotation if product is None else product * rotation
    return product


def rotation_from_angles(pitch: Tensor, roll: Tensor, yaw: Tensor | None = None) -> Tensor:
    """World-to-camera rotation ``R_z(roll) @ R_x(-pitch) @ R_y(-yaw)`` from angles in degrees.

    The three factors are kornia's ``So3`` rotations (:func:`axis_rotations`); the order is ours: kornia's Euler
    angles (``quaternion_from_euler``) compose ``R_z R_y R_x`` with the roll about x, another order and other axes.

    Args:
        pitch: (B,) degrees, > 0 looking up.
        roll: (B,) degrees, > 0 when the scene's up leans right in the image.
        yaw: (B,) degrees, > 0 turned right; zero when omitted.

    Returns:
        (B, 3, 3) rotation matrices.

    Example:
        >>> rotation_from_angles(torch.zeros(1), torch.zeros(1))
        tensor([[[1., 0., 0.],
                 [0., 1., 0.],
                 [0., 0., 1.]]])
    """
    KORNIA_CHECK_SHAPE(pitch, ["B"])
    yaw = torch.zeros_like(pitch) if yaw is None else yaw
    return axis_rotations((2, roll), (0, -pitch), (1, -yaw)).matrix()


def up_from_rotation(R: Tensor) -> Tensor:
    """The world up direction in camera coordinates, ``-R[..., :, 1]``: (B, 3, 3) -> (B, 3)."""
    KORNIA_CHECK_SHAPE(R, ["*", "3", "3"])
    return -R[..., :, 1]


def pitch_roll_from_up(up: Tensor) -> tuple[Tensor, Tensor]:
    """Pitch and roll in degrees from an up vector in camera coordinates.

    Ours: the angles of this package's convention (see the module docstring), which kornia does not know.

    Args:
        up: (B, 3) up direction (any positive length).

    Returns:
        pitch (B,), roll (B,) in degrees.

    Example:
        >>> pitch_roll_from_up(torch.tensor([[0.0, -1.0, 0.0]]))
        (tensor([0.]), tensor([0.]))
    """
    KORNIA_CHECK_SHAPE(up, ["*", "3"])
    u = normalize(up)
    pitch = torch.rad2deg(torch.asin(u[..., 2].clamp(-1.0, 1.0)))
    roll = torch.rad2deg(torch.atan2(u[..., 0], -u[..., 1]))
    return pitch, roll


def angles_from_rotation(R: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Pitch, roll and yaw in degrees from a world-to-camera rotation; inverse of :func:`rotation_from_angles`.

    Ours, for the order of :func:`rotation_from_angles`, which kornia's ``euler_from_quaternion`` does not use.

    Args:
        R: (B, 3, 3) rotation matrices.

    Returns:
        pitch (B,), roll (B,), yaw (B,) in degrees.

    Example:
        >>> R = rotation_from_angles(torch.tensor([10.0]), torch.tensor([-5.0]), torch.tensor([30.0]))
        >>> [round(float(a), 4) for a in angles_from_rotation(R)]
        [10.0, -5.0, 30.0]
    """
    KORNIA_CHECK_SHAPE(R, ["*", "3", "3"])
    pitch, roll = pitch_roll_from_up(up_from_rotation(R))
    # the camera's forward axis in the world, R^T e_z = R[2] = (sin(yaw) cos(pitch), -sin(pitch), cos(yaw) cos(pitch))
    yaw = torch.rad2deg(torch.atan2(R[..., 2, 0], R[..., 2, 2]))
    return pitch, roll, yaw


def zenith_from_up(K: Tensor, up: Tensor) -> Tensor:
    """Zenith vanishing point ``K @ up`` in homogeneous pixels: (B, 3, 3), (B, 3) -> (B, 3).

    Not kornia's ``project_points``, which divides by ``z``: the zenith of a level camera lies at infinity.
    """
    KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
    KORNIA_CHECK_SHAPE(up, ["*", "3"])
    return (K @ up.unsqueeze(-1)).squeeze(-1)


def up_from_zenith(K: Tensor, zenith: Tensor) -> Tensor:
    """Unit up vector in camera coordinates from a homogeneous zenith VP (sign fixed so the up vector points up
    in the image, ``up_y <= 0``).

    Not kornia's ``unproject_points``, which takes Euclidean pixels: the zenith may lie at infinity.

    Args:
        K: (B, 3, 3) intrinsics.
        zenith: (B, 3) homogeneous zenith in pixels (a point at infinity is allowed).

    Returns:
        (B, 3) unit up vectors.

    Example:
        >>> K = intrinsics_matrix(torch.tensor([100.0]), torch.tensor([0.0, 0.0]))
        >>> up_from_zenith(K, torch.tensor([[0.0, 1.0, 0.0]])).tolist()  # zenith far below: level camera
        [[0.0, -1.0, 0.0]]
    """
    KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
    KORNIA_CHECK_SHAPE(zenith, ["*", "3"])
    d = torch.linalg.solve(K, zenith.unsqueeze(-1)).squeeze(-1)
    sign = torch.where(d[..., 1:2] > 0, -1.0, 1.0).to(d)
    return normalize(d * sign)


def horizon_from_zenith(K: Tensor, zenith: Tensor) -> Tensor:
    """Horizon line ``K^-T K^-1 z`` (the image of the plane orthogonal to the vertical), normalised so that
    ``a^2 + b^2 = 1`` and ``b >= 0``. Ours: kornia has no vanishing line of a plane.

    Args:
        K: (B, 3, 3) intrinsics.
        zenith: (B, 3) homogeneous zenith VP in pixels.

    Returns:
        (B, 3) horizon lines ``(a, b, c)``, ``a x + b y + c = 0`` in pixels.

    Example:
        >>> K = intrinsics_matrix(torch.tensor([100.0]), torch.tensor([50.0, 40.0]))
        >>> horizon_from_zenith(K, torch.tensor([[0.0, 1.0, 0.0]]))  # level camera: y = c_y
        tensor([[  0.,   1., -40.]])
    """
    KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
    KORNIA_CHECK_SHAPE(zenith, ["*", "3"])
    d = torch.linalg.solve(K, zenith.unsqueeze(-1))
    line = torch.linalg.solve(K.transpose(-1, -2), d).squeeze(-1)
    return _normalize_line(line)


def _normalize_line(line: Tensor) -> Tensor:
    ab = torch.linalg.vector_norm(line[..., :2], dim=-1, keepdim=True).clamp_min(_eps(line))
    sign = torch.where(line[..., 1:2] < 0, -1.0, 1.0).to(line)
    return line * sign / ab


def zenith_from_horizon(K: Tensor, horizon: Tensor) -> Tensor:
    """Zenith VP ``K K^T l`` from a horizon line; inverse of :func:`horizon_from_zenith` up to scale. Ours: kornia
    has no pole of a vanishing line.

    Args:
        K: (B, 3, 3) intrinsics.
        horizon: (B, 3) horizon line in pixels.

    Returns:
        (B, 3) homogeneous zenith VP in pixels, unit norm, with the sign of ``K @ up``.
    """
    KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
    KORNIA_CHECK_SHAPE(horizon, ["*", "3"])
    d = (K.transpose(-1, -2) @ horizon.unsqueeze(-1)).squeeze(-1)
    sign = torch.where(d[..., 1:2] > 0, -1.0, 1.0).to(d)
    return normalize((K @ (d * sign).unsqueeze(-1)).squeeze(-1))


def horizon_border_points(horizon: Tensor, width: int | Tensor) -> Tensor:
    """Where the horizon crosses the left (``x = -0.5``) and right (``x = W - 0.5``) image borders.

    A vertical horizon (``b = 0``, roll of 90 degrees) has no crossing; ``b`` is clamped to a tiny positive value so
    the result stays finite (and very large). Ours: kornia's lines are parametric (``ParametrizedLine``), and
    intersecting one with a border ``Hyperplane`` has no such clamp.

    Args:
        horizon: (B, 3) lines ``(a, b, c)`` in pixels.
        width: image width in pixels.

    Returns:
        (B, 2, 2): ``[[x_left, y_left], [x_right, y_right]]``.

    Example:
        >>> horizon_border_points(torch.tensor([[0.0, 1.0, -100.0]]), 640).tolist()
        [[[-0.5, 100.0], [639.5, 100.0]]]
    """
    KORNIA_CHECK_SHAPE(horizon, ["*", "3"])
    h = _normalize_line(horizon)
    a, b, c = h.unbind(-1)
    b = b.clamp_min(1e-6)
    w = torch.as_tensor(width).to(h)
    xl, xr = torch.full_like(a, -0.5), w - 0.5 + torch.zeros_like(a)
    yl, yr = -(a * xl + c) / b, -(a * xr + c) / b
    return torch.stack([torch.stack([xl, yl], -1), torch.stack([xr, yr], -1)], -2)


def focal_from_orthogonal_vps(v1: Tensor, v2: Tensor, center: Tensor) -> tuple[Tensor, Tensor]:
    """Focal length from two vanishing points of orthogonal directions (square pixels, known principal point).

    Ours: kornia has no calibration from vanishing points.

    With ``p_i = v_i[:2] - c * v_i[2]`` the VPs relative to the principal point, orthogonality of
    ``K^-1 v_1`` and ``K^-1 v_2`` gives ``f^2 = -(p_1 . p_2) / (w_1 w_2)``.

    Args:
        v1: (..., 3) homogeneous VPs in pixels.
        v2: (..., 3) homogeneous VPs in pixels, broadcastable with ``v1``.
        center: (..., 2) or (2,) the principal point, broadcastable.

    Returns:
        focal (...,) in pixels and valid (...,) bool. Where ``f^2`` is not positive and finite (the two VPs cannot be
        orthogonal, or a VP is at infinity) valid is False and focal is 0.

    Example:
        >>> f, ok = focal_from_orthogonal_vps(torch.tensor([100.0, 0, 1]), torch.tensor([-400.0, 0, 1]),
        ...                                   torch.tensor([0.0, 0.0]))
        >>> f, ok
        (tensor(200.), tensor(True))
    """
    KORNIA_CHECK_SHAPE(v1, ["*", "3"])
    KORNIA_CHECK_SHAPE(v2, ["*", "3"])
    v1, v2 = normalize(v1), normalize(v2)
    c = center.to(v1)
    p1 = v1[..., :2] - c * v1[..., 2:]
    p2 = v2[..., :2] - c * v2[..., 2:]
    ww = v1[..., 2] * v2[..., 2]
    num = -(p1 * p2).sum(-1)
    tiny = 1e-12 if v1.dtype == torch.float64 else 1e-9
    valid = (ww.abs() > tiny) & (num * torch.sign(ww) > 0)
    f2 = torch.where(valid, num / torch.where(valid, ww, torch.ones_like(ww)), torch.ones_like(ww))
    focal = torch.where(valid, f2.clamp_min(_eps(f2)).sqrt(), torch.zeros_like(f2))
    return focal, valid


def rotation_from_vps(K: Tensor, zenith: Tensor, horizontal: Tensor) -> Tensor:
    """World-to-camera rotation from the zenith VP and one horizontal VP (Manhattan frame).

    Ours, as are the other Manhattan-frame functions below: kornia has no vanishing-point frames.

    The up axis comes from the zenith exactly; the horizontal VP's direction is made orthogonal to it, so a
    slightly non-orthogonal pair still yields a rotation. Columns: world x = the horizontal direction, world y =
    down, world z = x cross y. Use :func:`canonical_manhattan_rotation` to pick a canonical yaw.

    Args:
        K: (B, 3, 3) intrinsics.
        zenith: (B, 3) homogeneous zenith VP in pixels.
        horizontal: (B, 3) homogeneous horizontal VP in pixels.

    Returns:
        (B, 3, 3) rotation matrices.
    """
    return rotation_from_up(up_from_zenith(K, zenith), torch.linalg.solve(K, horizontal.unsqueeze(-1)).squeeze(-1))


def rotation_from_up(up: Tensor, horizontal: Tensor) -> Tensor:
    """World-to-camera rotation of a Manhattan frame from its up vector and a horizontal direction, both in camera
    coordinates: world y = down exactly, world x = the horizontal direction made orthogonal to up (so a slightly
    non-orthogonal pair still yields a rotation), world z = x cross y.

    Args:
        up: (B, 3) unit up vectors.
        horizontal: (B, 3) horizontal directions (any length).

    Returns:
        (B, 3, 3) rotation matrices.

    Example:
        >>> rotation_from_up(torch.tensor([[0.0, -1.0, 0.0]]), torch.tensor([[2.0, 0.1, 0.0]]))
        tensor([[[1., 0., 0.],
                 [0., 1., 0.],
                 [0., 0., 1.]]])
    """
    KORNIA_CHECK_SHAPE(up, ["*", "3"])
    KORNIA_CHECK_SHAPE(horizontal, ["*", "3"])
    h = normalize(horizontal - batched_dot_product(horizontal, up, keepdim=True) * up)
    down = -up
    return torch.stack([h, down, torch.linalg.cross(h, down)], -1)


def canonical_manhattan_rotation(R: Tensor) -> Tensor:
    """Resolve the four-fold yaw ambiguity of a Manhattan frame: world z becomes the horizontal axis closest to
    the optical axis (pointing forward), so the yaw lies in [-45, 45] degrees. World y (down) is kept.

    Args:
        R: (B, 3, 3) rotations whose column 1 is the down direction.

    Returns:
        (B, 3, 3) rotations.
    """
    KORNIA_CHECK_SHAPE(R, ["*", "3", "3"])
    cand = torch.stack([R[..., 0], R[..., 2], -R[..., 0], -R[..., 2]], -2)  # (..., 4, 3)
    best = cand[..., 2].argmax(-1)
    z = torch.gather(cand, -2, best[..., None, None].expand(*best.shape, 1, 3)).squeeze(-2)
    y = R[..., 1]
    return torch.stack([torch.linalg.cross(y, z), y, z], -1)


def vanishing_points_from_rotation(K: Tensor, R: Tensor) -> Tensor:
    """The three Manhattan VPs ``K @ R[:, i]``, homogeneous pixels, unit norm.

    Args:
        K: (B, 3, 3) intrinsics.
        R: (B, 3, 3) world-to-camera rotations.

    Returns:
        (B, 3, 3): row ``i`` is the VP of world axis ``i`` (row 1 is the vertical / zenith direction).
    """
    KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
    KORNIA_CHECK_SHAPE(R, ["*", "3", "3"])
    return normalize((K @ R).transpose(-1, -2))

