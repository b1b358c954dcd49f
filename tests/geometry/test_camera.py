"""Tests of ngp_kornia.geometry.camera: intrinsics, rotations, angles, field of view, horizon and zenith."""

import math

import pytest
import torch
from kornia.core.exceptions import BaseError, ShapeError
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from torch.autograd import gradcheck

from ngp_kornia.geometry.camera import (
    angles_from_rotation,
    canonical_manhattan_rotation,
    focal_from_fov,
    focal_from_orthogonal_vps,
    fov_from_focal,
    horizon_border_points,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    pitch_roll_from_up,
    rotation_from_angles,
    rotation_from_vps,
    up_from_rotation,
    up_from_zenith,
    vanishing_points_from_rotation,
    zenith_from_horizon,
    zenith_from_up,
)
from tests.synthetic_camera import BATCHES, H, W, camera_from_angles


def _angles(b, seed=0, dtype=torch.float64):
    """Random hand-held camera angles: |pitch| in [5, 30], |roll| < 20, yaw in [-40, 40] (away from zero pitch)."""
    g = torch.Generator().manual_seed(seed)
    sign = torch.where(torch.rand(b, generator=g) < 0.5, -1.0, 1.0)
    pitch = (sign * (5 + 25 * torch.rand(b, generator=g))).to(dtype)
    roll = ((torch.rand(b, generator=g) - 0.5) * 40).to(dtype)
    yaw = ((torch.rand(b, generator=g) - 0.5) * 80).to(dtype)
    focal = (300 + 500 * torch.rand(b, generator=g)).to(dtype)
    return pitch, roll, yaw, focal


def _project(K, R, X):
    """Project world points X (B, ..., 3) with a camera at the world origin: (B, ..., 2) pixels."""
    P = K @ R
    x = torch.einsum("bij,b...j->b...i", P, X)
    return x[..., :2] / x[..., 2:]


def _one(v, dtype=torch.float64):
    return torch.tensor([float(v)], dtype=dtype)


# ---------------------------------------------------------------------------------------------------------------
# normalize / image_center / intrinsics_matrix


def test_normalize_unit_and_zero(dtype):
    v = torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], dtype=dtype)
    out = normalize(v)
    assert out.dtype == dtype
    torch.testing.assert_close(out[0], torch.tensor([0.6, 0.8, 0.0], dtype=dtype))
    assert torch.equal(out[1], torch.zeros(3, dtype=dtype))  # zero stays zero, no NaN


def test_normalize_gradcheck():
    v = torch.tensor([[3.0, 4.0, 1.0], [-0.5, 0.2, 2.0]], dtype=torch.float64, requires_grad=True)
    assert gradcheck(normalize, (v,))


def test_normalize_dim():
    v = torch.tensor([[3.0, 0.0], [4.0, 2.0]])
    torch.testing.assert_close(normalize(v, dim=0), torch.tensor([[0.6, 0.0], [0.8, 1.0]]))


def test_convention_image_center_pixel_centres():
    # pixel centres are integers; a W-pixel image spans [-0.5, W - 0.5], so its centre is (W - 1) / 2
    torch.testing.assert_close(image_center(480, 640), torch.tensor([319.5, 239.5]))
    torch.testing.assert_close(image_center(1, 1), torch.tensor([0.0, 0.0]))
    torch.testing.assert_close(image_center(3, 2), torch.tensor([0.5, 1.0]))


def test_image_center_like(dtype):
    c = image_center(10, 20, like=torch.zeros(1, dtype=dtype))
    assert c.dtype == dtype and c.shape == (2,)


@pytest.mark.parametrize("b", BATCHES)
def test_intrinsics_matrix(b, dtype):
    f = torch.arange(1, b + 1, dtype=dtype) * 100
    K = intrinsics_matrix(f, torch.tensor([319.5, 239.5]))
    assert K.shape == (b, 3, 3) and K.dtype == dtype
    torch.testing.assert_close(K[:, 0, 0], f)
    torch.testing.assert_close(K[:, 1, 1], f)
    torch.testing.assert_close(K[:, :2, 2], torch.tensor([319.5, 239.5], dtype=dtype).expand(b, 2))
    assert torch.equal(K[:, 2], torch.tensor([0.0, 0.0, 1.0], dtype=dtype).expand(b, 3))
    assert torch.equal(K[:, 0, 1], torch.zeros(b, dtype=dtype)) and torch.equal(K[:, 1, 0], torch.zeros(b, dtype=dtype))
    # per-batch principal points
    pp = torch.arange(2 * b, dtype=dtype).reshape(b, 2)
    torch.testing.assert_close(intrinsics_matrix(f, pp)[:, :2, 2], pp)


def test_intrinsics_matrix_exception():
    with pytest.raises(ShapeError):
        intrinsics_matrix(torch.ones(2, 1), torch.zeros(2))


def test_intrinsics_matrix_gradcheck():
    f = torch.tensor([300.0, 500.0], dtype=torch.float64, requires_grad=True)
    pp = torch.tensor([[10.0, 20.0], [30.0, 40.0]], dtype=torch.float64, requires_grad=True)
    assert gradcheck(intrinsics_matrix, (f, pp))


# ---------------------------------------------------------------------------------------------------------------
# field of view


def test_fov_known_answers():
    torch.testing.assert_close(fov_from_focal(torch.tensor([320.0]), 640), torch.tensor([90.0]))
    torch.testing.assert_close(focal_from_fov(torch.tensor([90.0]), 640), torch.tensor([320.0]))
    f60 = 320.0 / math.tan(math.radians(30.0))
    torch.testing.assert_close(focal_from_fov(torch.tensor([60.0]), 640), torch.tensor([f60]))


@pytest.mark.parametrize("b", BATCHES)
def test_convention_round_trip_fov_focal(b, dtype):
    fov = torch.linspace(20.0, 150.0, b, dtype=dtype)
    f = focal_from_fov(fov, 640)
    assert f.dtype == dtype and f.shape == (b,)
    torch.testing.assert_close(fov_from_focal(f, 640), fov, rtol=1e-5, atol=1e-4)
    focal = torch.linspace(100.0, 2000.0, b, dtype=dtype)
    torch.testing.assert_close(focal_from_fov(fov_from_focal(focal, 480), 480), focal, rtol=1e-5, atol=1e-3)


def test_fov_tensor_size():
    out = fov_from_focal(torch.tensor([100.0, 200.0]), torch.tensor([200.0, 400.0]))
    torch.testing.assert_close(out, torch.tensor([90.0, 90.0]))


@pytest.mark.parametrize("bad", [0.0, 180.0, -10.0, 200.0])
def test_focal_from_fov_exception(bad):
    with pytest.raises(BaseError, match="fov_deg"):
        focal_from_fov(torch.tensor([60.0, bad]), 640)


def test_fov_gradcheck():
    f = torch.tensor([300.0, 800.0], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda x: fov_from_focal(x, 640), (f,))
    fov = torch.tensor([40.0, 100.0], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda x: focal_from_fov(x, 640), (fov,))


# ---------------------------------------------------------------------------------------------------------------
# rotations and angles


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[1.0, 0, 0], [0, c, -s], [0, s, c]], dtype=torch.float64)


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, 0, s], [0, 1.0, 0], [-s, 0, c]], dtype=torch.float64)


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1.0]], dtype=torch.float64)


def test_convention_rotation_order():
    p, r, y = 12.0, -7.0, 33.0
    expected = _rz(math.radians(r)) @ _rx(-math.radians(p)) @ _ry(-math.radians(y))
    R = rotation_from_angles(_one(p), _one(r), _one(y))
    torch.testing.assert_close(R[0], expected)
    # composition of single-angle rotations in the same order
    composed = (
        rotation_from_angles(_one(0), _one(r))
        @ rotation_from_angles(_one(p), _one(0))
        @ rotation_from_angles(_one(0), _one(0), _one(y))
    )
    torch.testing.assert_close(R, composed)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rotation_factors_are_kornias_axis_angle_rotations(axis, dtype):
    # each factor is the right-handed turn about its axis that kornia's Rodrigues formula gives; the two formulas
    # round differently (its unit diagonal entry is cos + (1 - cos)), hence a few ulps of tolerance
    angle = torch.linspace(-179.0, 179.0, 37, dtype=dtype)
    zero = torch.zeros_like(angle)
    # pitch turns about -x, yaw about -y, roll about +z
    args = {0: (-angle, zero, zero), 1: (zero, zero, -angle), 2: (zero, angle, zero)}[axis]
    axis_angle = torch.zeros(37, 3, dtype=dtype)
    axis_angle[:, axis] = torch.deg2rad(angle)
    eps = torch.finfo(dtype).eps
    torch.testing.assert_close(
        rotation_from_angles(*args), axis_angle_to_rotation_matrix(axis_angle), atol=8 * eps, rtol=0
    )


def test_rotation_from_angles_gradient_at_zero():
    # the level camera, where many training crops start: a finite, exact derivative
    angles = tuple(torch.zeros(2, dtype=torch.float64, requires_grad=True) for _ in range(3))
    assert gradcheck(rotation_from_angles, angles)


def test_rotation_from_angles_identity_and_default_yaw():
    torch.testing.assert_close(rotation_from_angles(torch.zeros(3), torch.zeros(3)), torch.eye(3).expand(3, 3, 3))
    p, r = torch.tensor([10.0, -20.0]), torch.tensor([5.0, 3.0])
    torch.testing.assert_close(rotation_from_angles(p, r), rotation_from_angles(p, r, torch.zeros(2)))


@pytest.mark.parametrize("b", BATCHES)
def test_rotation_from_angles_is_rotation(b, dtype):
    pitch, roll, yaw, _ = _angles(b, dtype=dtype)
    R = rotation_from_angles(pitch, roll, yaw)
    assert R.shape == (b, 3, 3) and R.dtype == dtype
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=dtype).expand(b, 3, 3), atol=tol, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(b, dtype=dtype), atol=tol, rtol=0)


def test_rotation_from_angles_exception():
    with pytest.raises(ShapeError):
        rotation_from_angles(torch.zeros(2, 1), torch.zeros(2, 1))


@pytest.mark.parametrize("b", BATCHES)
def test_convention_round_trip_angles_rotation(b, dtype):
    g = torch.Generator().manual_seed(b)
    pitch = ((torch.rand(b, generator=g) - 0.5) * 170).to(dtype)  # |pitch| < 85
    roll = ((torch.rand(b, generator=g) - 0.5) * 340).to(dtype)  # |roll| < 170
    yaw = ((torch.rand(b, generator=g) - 0.5) * 340).to(dtype)
    out = angles_from_rotation(rotation_from_angles(pitch, roll, yaw))
    tol = 2e-3 if dtype == torch.float32 else 1e-9
    for got, want in zip(out, (pitch, roll, yaw), strict=True):
        assert got.dtype == dtype and got.shape == (b,)
        torch.testing.assert_close(got, want, atol=tol, rtol=0)
    # and the other way round
    R = rotation_from_angles(pitch, roll, yaw)
    torch.testing.assert_close(rotation_from_angles(*out), R, atol=tol, rtol=0)


def test_up_from_rotation():
    R = rotation_from_angles(torch.zeros(1), torch.zeros(1))
    torch.testing.assert_close(up_from_rotation(R), torch.tensor([[0.0, -1.0, 0.0]]))
    R = rotation_from_angles(*_angles(4)[:3])
    torch.testing.assert_close(up_from_rotation(R), -R[:, :, 1])
    with pytest.raises(ShapeError):
        up_from_rotation(torch.zeros(2, 3, 4))


def test_convention_world_y_down():
    # level camera: the world up direction (0, -1, 0) is the camera's -y (image up); the zenith is at infinity upwards
    K, R = camera_from_angles(_one(0), _one(0), _one(0), _one(500))
    up = up_from_rotation(R)
    torch.testing.assert_close(up, torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64))
    z = zenith_from_up(K, up)
    assert z[0, 2] == 0 and z[0, 1] < 0
    # a point below the camera (world +y) projects below the image centre
    x = _project(K, R, torch.tensor([[[0.0, 1.0, 10.0]]], dtype=torch.float64))
    assert x[0, 0, 1] > (H - 1) / 2


@pytest.mark.parametrize("pitch", [5.0, 20.0, 45.0])
def test_convention_pitch_positive_horizon_below_centre(pitch):
    f = 500.0
    K, R = camera_from_angles(_one(pitch), _one(0), _one(0), _one(f))
    cx, cy = (W - 1) / 2, (H - 1) / 2
    up = up_from_rotation(R)
    p, r = pitch_roll_from_up(up)
    torch.testing.assert_close(p, _one(pitch))
    torch.testing.assert_close(p, torch.rad2deg(torch.asin(up[:, 2])))  # pitch = asin(up_z) > 0: looks up
    assert up[0, 2] > 0
    zenith = zenith_from_up(K, up)
    horizon = horizon_from_zenith(K, zenith)
    # horizon is horizontal and lies below the centre at y = c_y + f tan(pitch)
    y_h = cy + f * math.tan(math.radians(pitch))
    torch.testing.assert_close(horizon[0], torch.tensor([0.0, 1.0, -y_h], dtype=torch.float64))
    # the zenith lies above the centre at y = c_y - f / tan(pitch), on the vertical through the principal point
    zx, zy = (zenith[0, :2] / zenith[0, 2]).tolist()
    assert zx == pytest.approx(cx)
    assert zy == pytest.approx(cy - f / math.tan(math.radians(pitch)))
    # a far point straight ahead on the ground plane (world +z) projects onto the horizon
    x = _project(K, R, torch.tensor([[[0.0, 0.0, 1e9]]], dtype=torch.float64))
    assert x[0, 0, 1].item() == pytest.approx(y_h, abs=1e-4)


@pytest.mark.parametrize("roll", [3.0, 10.0, 30.0])
def test_convention_roll_positive_horizon_falls_left_to_right(roll):
    K, R = camera_from_angles(_one(5.0), _one(roll), _one(0), _one(500))
    up = up_from_rotation(R)
    assert up[0, 0] > 0  # the scene's up leans to the right
    _, r = pitch_roll_from_up(up)
    torch.testing.assert_close(r, _one(roll))
    torch.testing.assert_close(r, torch.rad2deg(torch.atan2(up[:, 0], -up[:, 1])))
    horizon = horizon_from_zenith(K, zenith_from_up(K, up))
    (xl, yl), (xr, yr) = horizon_border_points(horizon, W)[0].tolist()
    assert yr > yl  # right end lower (larger y)
    assert (yr - yl) / (xr - xl) == pytest.approx(math.tan(math.radians(roll)))
    # negative roll: the other way round
    K, R = camera_from_angles(_one(5.0), _one(-roll), _one(0), _one(500))
    horizon = horizon_from_zenith(K, zenith_from_up(K, up_from_rotation(R)))
    (_, yl), (_, yr) = horizon_border_points(horizon, W)[0].tolist()
    assert yr < yl


@pytest.mark.parametrize("yaw", [10.0, 30.0, 60.0])
def test_convention_yaw_positive_turned_right(yaw):
    f = 400.0
    K, R = camera_from_angles(_one(0), _one(0), _one(yaw), _one(f))
    cx, cy = (W - 1) / 2, (H - 1) / 2
    # a world point straight ahead along world +z appears left of the centre
    x = _project(K, R, torch.tensor([[[0.0, 0.0, 10.0]]], dtype=torch.float64))[0, 0]
    assert x[0].item() == pytest.approx(cx - f * math.tan(math.radians(yaw)))
    assert x[1].item() == pytest.approx(cy)
    # yaw does not move the up vector
    torch.testing.assert_close(up_from_rotation(R), torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64))
    _, _, y = angles_from_rotation(R)
    torch.testing.assert_close(y, _one(yaw))


@pytest.mark.parametrize("b", BATCHES)
def test_pitch_roll_from_up_scale_invariant(b, dtype):
    pitch, roll, yaw, _ = _angles(b, dtype=dtype)
    up = up_from_rotation(rotation_from_angles(pitch, roll, yaw))
    p, r = pitch_roll_from_up(3.7 * up)
    assert p.dtype == dtype and p.shape == (b,)
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(p, pitch, atol=tol, rtol=0)
    torch.testing.assert_close(r, roll, atol=tol, rtol=0)


def test_pitch_roll_from_up_exception():
    with pytest.raises(ShapeError, match="expected 3"):
        pitch_roll_from_up(torch.zeros(2, 4))


def test_angles_gradcheck():
    pitch, roll, yaw, _ = _angles(3)
    args = tuple(t.clone().requires_grad_() for t in (pitch, roll, yaw))
    assert gradcheck(rotation_from_angles, args)
    R = rotation_from_angles(pitch, roll, yaw).requires_grad_()
    assert gradcheck(angles_from_rotation, (R,))
    up = up_from_rotation(R.detach()).requires_grad_()
    assert gradcheck(pitch_roll_from_up, (up,))
    assert gradcheck(up_from_rotation, (R,))


# ---------------------------------------------------------------------------------------------------------------
# zenith, up and horizon


@pytest.mark.parametrize("b", BATCHES)
def test_convention_round_trip_up_zenith(b, dtype):
    pitch, roll, yaw, focal = _angles(b, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    up = up_from_rotation(R)
    zenith = zenith_from_up(K, up)
    assert zenith.shape == (b, 3) and zenith.dtype == dtype
    out = up_from_zenith(K, zenith)
    assert out.dtype == dtype
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(out, up, atol=tol, rtol=0)
    # homogeneous: any scale and sign of the zenith gives the same up vector
    torch.testing.assert_close(up_from_zenith(K, -2.5 * zenith), up, atol=tol, rtol=0)


def test_up_from_zenith_at_infinity():
    # level camera with roll: the zenith is a point at infinity, the up vector still comes out (unit, pointing up)
    K, R = camera_from_angles(_one(0), _one(10), _one(0), _one(500))
    up = up_from_rotation(R)
    zenith = zenith_from_up(K, up)
    assert abs(zenith[0, 2]) < 1e-12
    out = up_from_zenith(K, -zenith)
    torch.testing.assert_close(out, up)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("b", BATCHES)
def test_convention_round_trip_horizon_zenith(b, dtype):
    pitch, roll, yaw, focal = _angles(b, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    zenith = zenith_from_up(K, up_from_rotation(R))
    horizon = horizon_from_zenith(K, zenith)
    assert horizon.shape == (b, 3) and horizon.dtype == dtype
    back = zenith_from_horizon(K, horizon)
    assert back.dtype == dtype
    tol = 1e-4 if dtype == torch.float32 else 1e-10
    # unit norm, same sign as K @ up
    torch.testing.assert_close(back, normalize(zenith), atol=tol, rtol=0)
    torch.testing.assert_close(horizon_from_zenith(K, back), horizon, atol=tol * 1e3, rtol=tol)
    # a horizon given with the opposite sign is the same line
    torch.testing.assert_close(zenith_from_horizon(K, -3 * horizon), back, atol=tol, rtol=0)


def test_convention_horizon_normalisation(dtype):
    pitch, roll, yaw, focal = _angles(5, seed=3, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    zenith = zenith_from_up(K, up_from_rotation(R))
    for z in (zenith, -zenith, 7 * zenith):
        h = horizon_from_zenith(K, z)
        torch.testing.assert_close(h[:, :2].norm(dim=-1), torch.ones(5, dtype=dtype))
        assert (h[:, 1] >= 0).all()
    torch.testing.assert_close(horizon_from_zenith(K, -zenith), horizon_from_zenith(K, zenith))


def test_horizon_is_image_of_horizontal_points():
    # every world point at infinity in a horizontal direction projects onto the horizon
    pitch, roll, yaw, focal = _angles(3, seed=5)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    horizon = horizon_from_zenith(K, zenith_from_up(K, up_from_rotation(R)))
    az = torch.linspace(-0.6, 0.6, 7, dtype=torch.float64)
    dirs = torch.stack([torch.sin(az), torch.zeros_like(az), torch.cos(az)], -1)  # (7, 3) world, in front
    x = _project(K, R, dirs.expand(3, 7, 3))
    res = (horizon[:, None, :2] * x).sum(-1) + horizon[:, None, 2]
    assert res.abs().max() < 1e-8


def test_horizon_from_zenith_at_infinity():
    # level camera: zenith at infinity, horizon is y = c_y
    K = intrinsics_matrix(torch.tensor([100.0]), torch.tensor([50.0, 40.0]))
    torch.testing.assert_close(horizon_from_zenith(K, torch.tensor([[0.0, -1.0, 0.0]])), torch.tensor([[0, 1, -40.0]]))


def test_zenith_horizon_exceptions():
    K = torch.eye(3)[None]
    with pytest.raises(ShapeError):
        zenith_from_up(K, torch.zeros(1, 2))
    with pytest.raises(ShapeError):
        zenith_from_up(torch.zeros(1, 3, 2), torch.zeros(1, 3))
    with pytest.raises(ShapeError):
        up_from_zenith(K, torch.zeros(1, 4))
    with pytest.raises(ShapeError):
        horizon_from_zenith(K, torch.zeros(1, 2))
    with pytest.raises(ShapeError):
        zenith_from_horizon(torch.zeros(1, 2, 3), torch.zeros(1, 3))
    with pytest.raises(ShapeError):
        horizon_border_points(torch.zeros(1, 2), 10)


def test_zenith_horizon_gradcheck():
    pitch, roll, yaw, focal = _angles(2, seed=1)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    up = up_from_rotation(R)
    zenith = zenith_from_up(K, up)
    horizon = horizon_from_zenith(K, zenith)
    Kg = K.clone().requires_grad_()
    assert gradcheck(zenith_from_up, (Kg, up.clone().requires_grad_()))
    assert gradcheck(up_from_zenith, (Kg, zenith.clone().requires_grad_()))
    assert gradcheck(horizon_from_zenith, (Kg, zenith.clone().requires_grad_()))
    assert gradcheck(zenith_from_horizon, (Kg, horizon.clone().requires_grad_()))
    assert gradcheck(lambda h: horizon_border_points(h, W), (horizon.clone().requires_grad_(),))


# ---------------------------------------------------------------------------------------------------------------
# horizon_border_points


@pytest.mark.parametrize("b", BATCHES)
def test_horizon_border_points(b, dtype):
    g = torch.Generator().manual_seed(b)
    ang = ((torch.rand(b, generator=g) - 0.5) * 60).to(dtype)
    y0 = (100 + 200 * torch.rand(b, generator=g)).to(dtype)
    # the line through (W/2, y0) at angle ang: -sin x + cos y + c = 0
    a, bb = -torch.sin(torch.deg2rad(ang)), torch.cos(torch.deg2rad(ang))
    c = -(a * (W / 2) + bb * y0)
    line = torch.stack([a, bb, c], -1)
    pts = horizon_border_points(-2 * line, W)  # any scale and sign
    assert pts.shape == (b, 2, 2) and pts.dtype == dtype
    torch.testing.assert_close(pts[:, 0, 0], torch.full((b,), -0.5, dtype=dtype))
    torch.testing.assert_close(pts[:, 1, 0], torch.full((b,), W - 0.5, dtype=dtype))
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    res = (pts * line[:, None, :2]).sum(-1) + line[:, None, 2]
    assert res.abs().max() < tol


def test_horizon_border_points_vertical_horizon_finite():
    pts = horizon_border_points(torch.tensor([[1.0, 0.0, -100.0]]), W)
    assert torch.isfinite(pts).all()


# ---------------------------------------------------------------------------------------------------------------
# vanishing points, focal length and Manhattan frames


@pytest.mark.parametrize("b", BATCHES)
def test_vanishing_points_from_rotation(b, dtype):
    pitch, roll, yaw, focal = _angles(b, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    vps = vanishing_points_from_rotation(K, R)
    assert vps.shape == (b, 3, 3) and vps.dtype == dtype
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for i in range(3):
        torch.testing.assert_close(vps[:, i], normalize((K @ R[:, :, i : i + 1])[..., 0]), atol=tol, rtol=0)
    torch.testing.assert_close(vps.norm(dim=-1), torch.ones(b, 3, dtype=dtype))
    # row 1 is the zenith direction (up to sign)
    cos = (vps[:, 1] * normalize(zenith_from_up(K, up_from_rotation(R)))).sum(-1).abs()
    torch.testing.assert_close(cos, torch.ones(b, dtype=dtype))


def test_vanishing_points_far_points_converge():
    # a far point along world axis i projects at the (finite) VP of axis i
    K, R = camera_from_angles(_one(15), _one(5), _one(30), _one(500))
    vps = vanishing_points_from_rotation(K, R)
    for i in range(3):
        d = torch.zeros(1, 1, 3, dtype=torch.float64)
        d[..., i] = 1e9 if (R[0, 2, i] > 0) else -1e9  # in front of the camera
        x = _project(K, R, d)[0, 0]
        torch.testing.assert_close(x, vps[0, i, :2] / vps[0, i, 2], rtol=1e-6, atol=1e-4)


def test_vanishing_points_exception():
    with pytest.raises(ShapeError):
        vanishing_points_from_rotation(torch.eye(3)[None], torch.eye(4)[None])


@pytest.mark.parametrize("b", BATCHES)
def test_focal_from_orthogonal_vps_recovers_focal(b, dtype):
    pitch, roll, yaw, focal = _angles(b, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    vps = (K @ R).transpose(-1, -2)
    pp = image_center(H, W, like=focal)
    for i, j in ((0, 1), (1, 2), (0, 2)):
        f, ok = focal_from_orthogonal_vps(vps[:, i], -3 * vps[:, j], pp)
        assert f.shape == (b,) and f.dtype == dtype and ok.dtype == torch.bool
        assert ok.all()
        torch.testing.assert_close(f, focal, rtol=1e-3 if dtype == torch.float32 else 1e-9, atol=0)


def test_focal_from_orthogonal_vps_known_answer_and_broadcast():
    f, ok = focal_from_orthogonal_vps(
        torch.tensor([[100.0, 0, 1], [0, 50, 1]]), torch.tensor([-400.0, 0, 1]), torch.tensor([0.0, 0.0])
    )
    torch.testing.assert_close(f, torch.tensor([200.0, 0.0]))
    assert ok.tolist() == [True, False]  # (0, 50) and (-400, 0) are orthogonal directions only for f = 0


def test_focal_from_orthogonal_vps_degenerate():
    pp = torch.tensor([0.0, 0.0])
    # both VPs on the same side of the principal point: cannot be orthogonal
    f, ok = focal_from_orthogonal_vps(torch.tensor([100.0, 0, 1]), torch.tensor([400.0, 0, 1]), pp)
    assert not ok and f == 0
    # a VP at infinity
    f, ok = focal_from_orthogonal_vps(torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 400, 1]), pp)
    assert not ok and f == 0
    # zero vectors
    f, ok = focal_from_orthogonal_vps(torch.zeros(3), torch.zeros(3), pp)
    assert not ok and f == 0 and torch.isfinite(f)


def test_focal_from_orthogonal_vps_exception():
    with pytest.raises(ShapeError):
        focal_from_orthogonal_vps(torch.zeros(2), torch.zeros(3), torch.zeros(2))


def test_focal_from_orthogonal_vps_gradcheck():
    K, R = camera_from_angles(*_angles(2, seed=4))
    vps = (K @ R).transpose(-1, -2)
    v1 = vps[:, 0].clone().requires_grad_()
    v2 = vps[:, 1].clone().requires_grad_()
    pp = image_center(H, W, like=v1).requires_grad_()
    assert gradcheck(lambda a, b, c: focal_from_orthogonal_vps(a, b, c)[0], (v1, v2, pp))


@pytest.mark.parametrize("b", BATCHES)
def test_rotation_from_vps_recovers_rotation(b, dtype):
    pitch, roll, yaw, focal = _angles(b, dtype=dtype)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    vps = (K @ R).transpose(-1, -2)
    tol = 1e-4 if dtype == torch.float32 else 1e-10
    for hi in (0, 2):  # either horizontal VP, any homogeneous sign
        out = rotation_from_vps(K, -vps[:, 1], -2 * vps[:, hi])
        assert out.shape == (b, 3, 3) and out.dtype == dtype
        torch.testing.assert_close(
            out @ out.transpose(-1, -2), torch.eye(3, dtype=dtype).expand(b, 3, 3), atol=tol, rtol=0
        )
        torch.testing.assert_close(torch.linalg.det(out), torch.ones(b, dtype=dtype), atol=tol, rtol=0)
        # the up vector is exact, the horizontal axis is the chosen one up to sign
        torch.testing.assert_close(up_from_rotation(out), up_from_rotation(R), atol=tol, rtol=0)
        cos = (out[:, :, 0] * R[:, :, hi]).sum(-1).abs()
        torch.testing.assert_close(cos, torch.ones(b, dtype=dtype), atol=tol, rtol=0)


def test_rotation_from_vps_non_orthogonal_input():
    K, R = camera_from_angles(*_angles(3, seed=2))
    vps = (K @ R).transpose(-1, -2)
    noisy = vps[:, 0] + torch.tensor([5.0, -3.0, 0.0], dtype=torch.float64) * vps[:, 0, 2:]
    out = rotation_from_vps(K, vps[:, 1], noisy)
    torch.testing.assert_close(out @ out.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(3, 3, 3))
    torch.testing.assert_close(up_from_rotation(out), up_from_rotation(R))


def test_rotation_from_vps_gradcheck():
    K, R = camera_from_angles(*_angles(2, seed=6))
    vps = (K @ R).transpose(-1, -2)
    z = vps[:, 1].clone().requires_grad_()
    h = vps[:, 0].clone().requires_grad_()
    assert gradcheck(lambda a, b: rotation_from_vps(K, a, b), (z, h))


@pytest.mark.parametrize("yaw", [-170.0, -100.0, -60.0, -30.0, 0.0, 20.0, 50.0, 95.0, 130.0, 179.0])
def test_canonical_manhattan_rotation(yaw, dtype):
    def t(v):
        return torch.tensor([v], dtype=dtype)

    R = rotation_from_angles(t(12.0), t(-8.0), t(yaw))
    # any of the 4 relabellings of the horizontal axes that keeps column 1 (yaw 135 would be a tie, so not tested)
    for k in range(4):
        Rk = R @ rotation_from_angles(t(0.0), t(0.0), t(90.0 * k)).transpose(-1, -2)
        out = canonical_manhattan_rotation(Rk)
        assert out.dtype == dtype and out.shape == (1, 3, 3)
        torch.testing.assert_close(out[:, :, 1], R[:, :, 1])  # column 1 kept
        torch.testing.assert_close(torch.linalg.det(out), torch.ones(1, dtype=dtype))
        p, r, y = angles_from_rotation(out)
        assert -45.0 - 1e-3 <= float(y) <= 45.0 + 1e-3
        expected = (yaw + 45.0) % 90.0 - 45.0
        assert float(y) == pytest.approx(expected, abs=1e-3)
        assert float(p) == pytest.approx(12.0, abs=1e-3) and float(r) == pytest.approx(-8.0, abs=1e-3)
        assert out[0, 2, 2] > 0  # world z points forward


@pytest.mark.parametrize("b", BATCHES)
def test_canonical_manhattan_rotation_batch_idempotent(b):
    pitch, roll, _, _ = _angles(b)
    yaw = torch.linspace(-170, 170, b, dtype=torch.float64)
    out = canonical_manhattan_rotation(rotation_from_angles(pitch, roll, yaw))
    torch.testing.assert_close(canonical_manhattan_rotation(out), out)


def test_canonical_manhattan_rotation_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        canonical_manhattan_rotation(torch.zeros(1, 3, 2))
    R = rotation_from_angles(*_angles(2, seed=8)[:3]).requires_grad_()
    assert gradcheck(canonical_manhattan_rotation, (R,))
    K = intrinsics_matrix(
        torch.tensor([400.0, 600.0], dtype=torch.float64), torch.tensor([10.0, 20.0])
    ).requires_grad_()
    assert gradcheck(vanishing_points_from_rotation, (K, R))
