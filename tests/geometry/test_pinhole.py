"""The camera object (ngp_kornia.geometry.pinhole.Camera): parameters in, the geometry derived from them, kornia's
camera types out; on every device and dtype, differentiable, a batch the same as its cameras alone."""

import pytest
import torch
from kornia.core.exceptions import ShapeError
from kornia.geometry.camera import PinholeCamera
from kornia.geometry.vector import Vector3
from kornia.sensors.camera import CameraModel
from torch.autograd import gradcheck

from ngp_kornia.geometry import (
    Camera,
    distort_points,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    rotation_from_angles,
    vanishing_points_from_rotation,
    zenith_from_up,
)

H, W = 480, 640
PITCH, ROLL, YAW, FOCAL = [8.0, -12.0, 3.0], [3.0, -5.0, 0.5], [20.0, -35.0, 10.0], [500.0, 700.0, 350.0]


def _camera(device=None, dtype=torch.float64, k1=None) -> Camera:
    kw = {"device": device, "dtype": dtype}
    point = torch.tensor([[319.5, 239.5], [300.0, 250.0], [330.0, 220.0]], **kw)
    k1 = None if k1 is None else torch.tensor(k1, **kw)
    return Camera.from_angles(
        torch.tensor(FOCAL, **kw), *(torch.tensor(v, **kw) for v in (PITCH, ROLL, YAW)),
        image_size=(H, W), center=point, lens=k1,
    )  # fmt: skip


def test_parameters_and_the_geometry_that_follows(device, dtype):
    camera = _camera(device, dtype)
    K = intrinsics_matrix(camera.focal, camera.center)
    R = rotation_from_angles(*(torch.tensor(v, device=device, dtype=dtype) for v in (PITCH, ROLL, YAW)))
    torch.testing.assert_close(camera.K, K)
    torch.testing.assert_close(camera.R, R)
    assert camera.K.device.type == device.type and camera.K.dtype == dtype and camera.image_size.dtype == torch.long
    tol = {"atol": 1e-4, "rtol": 1e-4} if dtype == torch.float32 else {}
    for got, want in zip((camera.pitch, camera.roll, camera.yaw), (PITCH, ROLL, YAW), strict=True):
        torch.testing.assert_close(got, torch.tensor(want, device=device, dtype=dtype), **tol)
    torch.testing.assert_close(camera.fov_v, fov_from_focal(camera.focal, H))
    torch.testing.assert_close(camera.fov_h, fov_from_focal(camera.focal, W))
    torch.testing.assert_close(camera.up, -R[..., 1])
    zenith = zenith_from_up(K, -R[..., 1])
    torch.testing.assert_close(camera.zenith, zenith / zenith.norm(dim=-1, keepdim=True))
    torch.testing.assert_close(camera.horizon, horizon_from_zenith(K, camera.zenith))
    torch.testing.assert_close(camera.vps, vanishing_points_from_rotation(K, R))


def test_convention_the_horizon_is_the_image_of_the_level_plane():
    camera = _camera()
    # world points on the horizon: level directions (world y = 0), seen through K R, lie on the horizon line
    level = torch.tensor([[1.0, 0.0, 2.0], [-1.0, 0.0, 3.0], [0.3, 0.0, 1.0]], dtype=torch.float64)
    pixels = torch.einsum("bij,nj->bni", camera.K @ camera.R, level)
    distance = (pixels * camera.horizon[:, None]).sum(-1) / pixels[..., 2]
    assert float(distance.abs().max()) < 1e-9


def test_from_matrix_reads_what_from_angles_built():
    camera = _camera()
    again = Camera.from_matrix(camera.K, camera.R, camera.image_size)
    assert torch.equal(again.params, camera.params) and torch.equal(again.horizon, camera.horizon)
    assert again.lens is None and torch.equal(camera.center, camera.K[:, :2, 2])


def test_centred_principal_point_by_default():
    camera = Camera.from_angles(torch.tensor([400.0]), torch.zeros(1), torch.zeros(1), image_size=(H, W))
    torch.testing.assert_close(camera.center[0], image_center(H, W))
    torch.testing.assert_close(camera.horizon, torch.tensor([[0.0, 1.0, -(H - 1) / 2.0]]))  # level: the middle row


def test_a_batch_is_its_cameras_alone(device):
    camera = _camera(device)
    for i in range(len(camera)):
        alone = Camera(camera.params[i], camera.R[i], camera.image_size[i])
        for name in ("K", "fov_v", "fov_h", "up", "zenith", "horizon", "vps", "pitch", "roll", "yaw"):
            torch.testing.assert_close(getattr(camera[i], name), getattr(alone, name), msg=name)
            assert torch.equal(getattr(camera[i], name), getattr(camera, name)[i]), name  # indexed from the batch


def test_kornia_pinhole_camera_projects_as_K_R(device, dtype):
    camera = _camera(device, dtype)
    kornia_camera = camera.to_kornia()
    assert isinstance(kornia_camera, PinholeCamera) and kornia_camera.intrinsics.shape == (3, 4, 4)
    assert kornia_camera.height.tolist() == [H] * 3 and kornia_camera.width.tolist() == [W] * 3
    X = torch.tensor([[1.0, -2.0, 6.0], [0.5, 0.3, 4.0], [-3.0, 1.0, 9.0]], device=device, dtype=dtype)
    x = (camera.K @ camera.R @ X[..., None])[..., 0]
    tol = {"atol": 1e-3, "rtol": 1e-5} if dtype == torch.float32 else {}
    torch.testing.assert_close(kornia_camera.project(X[:, None])[:, 0], x[:, :2] / x[:, 2:], **tol)
    one = camera[1].to_kornia()  # an unbatched camera: a batch of one
    assert one.intrinsics.shape == (1, 4, 4) and torch.equal(one.extrinsics[0, :3, :3], camera.R[1])


def test_kornia_camera_model_of_a_pinhole_projects_as_K(device, dtype):
    camera = _camera(device, dtype)
    model = camera.to_camera_model()
    assert isinstance(model, CameraModel) and type(model._model).__name__ == "PinholeModel"
    torch.testing.assert_close(model.K(), camera.K)
    d = torch.tensor([[0.2, -0.1, 1.0], [-0.3, 0.05, 2.0], [0.0, 0.4, 0.5]], device=device, dtype=dtype)
    x = (camera.K @ d[..., None])[..., 0]
    tol = {"atol": 1e-3, "rtol": 1e-5} if dtype == torch.float32 else {}
    # (B, 3) points, one per camera: kornia pairs batched parameters with points along the last point axis
    torch.testing.assert_close(model.project(Vector3(d)).data, x[:, :2] / x[:, 2:], **tol)


def test_kornia_camera_model_with_distortion_is_the_closest_brown_conrady():
    camera = _camera(k1=[-0.2, -0.05, 0.0])
    model = camera.to_camera_model()
    assert type(model._model).__name__ == "BrownConradyModel" and model.params.shape == (3, 12)
    assert torch.equal(model.params[:, :4], camera.params) and not model.params[:, [6, 7, 9, 10, 11]].any()
    for i in range(3):
        one = camera[i].to_camera_model()
        # rays across the image: kornia's polynomial lands within a pixel of the division model's distorted pixel
        grid = torch.stack(torch.meshgrid(torch.linspace(20, W - 20, 7), torch.linspace(20, H - 20, 5), indexing="xy"))
        pinhole = grid.reshape(2, -1).T.double()
        rays = torch.cat([(pinhole - camera.center[i]) / camera.focal[i], torch.ones(len(pinhole), 1)], -1)
        kornia_pixels = one.project(Vector3(rays)).data
        ours = distort_points(pinhole[None], camera.K[i : i + 1], camera.lens[i : i + 1])[0]
        assert float((kornia_pixels - ours).norm(dim=-1).max()) < 1.0, i
    assert not model.params[2, 4:].any()  # k1 = 0: no distortion


def test_rotation_is_kornias_so3():
    camera = _camera()
    torch.testing.assert_close(camera.rotation.matrix(), camera.R)


def test_gradcheck_geometry_of_the_parameters():
    camera = _camera()

    def geometry(params, angles):
        R = rotation_from_angles(*angles.unbind(-1))
        cam = Camera(params, R, camera.image_size)
        return torch.cat([cam.horizon, cam.zenith, cam.vps.flatten(1), torch.stack(
            [cam.fov_v, cam.fov_h, cam.pitch, cam.roll, cam.yaw], -1)], -1)  # fmt: skip

    params = camera.params.clone().requires_grad_()
    angles = torch.tensor([PITCH, ROLL, YAW], dtype=torch.float64).T.contiguous().requires_grad_()
    assert gradcheck(geometry, (params, angles))


def test_to_clone_apply_replace(device):
    camera = _camera(k1=[-0.1, 0.0, 0.1])
    moved = camera.to(device, torch.float32)
    assert moved.params.dtype == torch.float32 and moved.lens.dtype == torch.float32
    assert moved.image_size.dtype == torch.long and moved.image_size.device.type == device.type
    copy = camera.clone()
    assert copy.params is not camera.params and torch.equal(copy.params, camera.params)
    assert camera.apply(lambda t: t[:2]).params.shape == (2, 4)
    flat = camera.replace(lens=None)
    assert flat.lens is None and torch.equal(flat.R, camera.R)
    with pytest.raises(TypeError, match="unknown parameters"):
        camera.replace(focal=1.0)


def test_shapes_are_checked():
    camera = _camera()
    with pytest.raises(ShapeError, match="share one batch dim"):
        Camera(camera.params, camera.R[:2], camera.image_size)
    with pytest.raises(ShapeError, match="lens must be of shape"):
        Camera(camera.params, camera.R, camera.image_size, torch.zeros(2))
    with pytest.raises(ValueError):
        Camera(camera.params[:, :3], camera.R, camera.image_size)
    with pytest.raises(TypeError, match="unbatched"):
        camera[0][0]


def test_a_value_first_read_without_autograd_keeps_its_gradient_after():
    camera = _camera()
    params = camera.params.clone().requires_grad_()
    camera = camera.replace(params=params)
    with torch.no_grad():
        assert not camera.horizon.requires_grad and not camera[0].zenith.requires_grad
    camera.horizon.sum().backward()  # read again with autograd on: computed again, with its graph
    assert params.grad is not None and bool(params.grad.abs().sum() > 0)


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_precision_is_derived_in_float32_and_kept_in_its_dtype(half):
    camera = _camera()
    low = Camera(camera.params.to(half), camera.R.to(half), camera.image_size)
    assert low.horizon.dtype == half and low.pitch.dtype == half
    torch.testing.assert_close(low.horizon.double(), camera.horizon, atol=0.5, rtol=1e-2)
    cast = camera.to(half)  # cast from the float64 camera: its derived values, cast
    assert torch.equal(cast.horizon, camera.horizon.to(half))
