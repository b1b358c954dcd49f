"""Calibration.to_kornia / to_opencv / to_colmap: round trips against kornia's and OpenCV's own projection and
COLMAP's corner pixel origin."""

import json

import cv2
import numpy as np
import pytest
import torch
from kornia.geometry.camera import PinholeCamera

from ngp_kornia import calibrate
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def cal():
    return calibrate(render_scene(7, (320, 240)).image, weights="none")


@pytest.fixture(scope="module")
def points():
    """World points in front of the camera (in any frame whose z is roughly forward)."""
    g = torch.Generator().manual_seed(0)
    unit = torch.rand(20, 3, generator=g, dtype=torch.float64)
    return unit * torch.tensor([4.0, 3.0, 5.0]) - torch.tensor([2.0, 1.5, -2.0])


def _ours(cal, X):
    """Our pixels of world points: K R X, dehomogenised."""
    p = X @ (cal.K.double() @ cal.R.double()).T
    return p[:, :2] / p[:, 2:]


def test_to_kornia_is_a_batched_pinhole_camera(cal):
    camera = cal.to_kornia()
    assert isinstance(camera, PinholeCamera)
    assert camera.intrinsics.shape == (1, 4, 4) and camera.extrinsics.shape == (1, 4, 4)
    assert camera.height.tolist() == [240.0] and camera.width.tolist() == [320.0]
    assert torch.equal(camera.intrinsics[0, :3, :3], cal.K) and torch.equal(camera.rotation_matrix[0], cal.R)
    assert torch.equal(camera.translation_vector[0], torch.zeros(3, 1, dtype=cal.K.dtype))


def test_kornia_projection_equals_ours(cal, points):
    world = points @ cal.R.double()  # rotate into world so all of them lie in front of the camera
    camera = cal.to(torch.float64).to_kornia()
    projected = camera.project(world)
    assert torch.allclose(projected, _ours(cal.to(torch.float64), world), atol=1e-9)
    # and back: kornia's unprojection of those pixels at the camera-frame depth returns the world points
    depth = (world @ cal.R.double().T)[:, 2:]
    assert torch.allclose(camera.unproject(projected, depth), world, atol=1e-9)


def test_kornia_projects_world_axes_to_the_vanishing_points(cal):
    camera = cal.to(torch.float64).to_kornia()
    for axis in range(3):
        direction = torch.zeros(1, 3, dtype=torch.float64)
        direction[0, axis] = 1.0
        sign = 1.0 if float((cal.R.double() @ direction[0])[2]) > 0 else -1.0  # the half in front of the camera
        far = camera.project(sign * 1e6 * direction)[0]
        vp = cal.vps[axis].double()
        if abs(float(vp[2])) > 1e-3:
            assert torch.allclose(far, vp[:2] / vp[2], rtol=1e-4, atol=1e-2)


def test_batched_calibration_gives_a_batched_camera():
    images = torch.stack([torch.from_numpy(render_scene(s, (160, 120)).image) for s in (1, 2)])
    batch = calibrate(images.permute(0, 3, 1, 2).float() / 255, weights="none")
    camera = batch.to_kornia()
    assert camera.batch_size == 2 and camera.intrinsics.shape == (2, 4, 4)
    assert torch.equal(camera.intrinsics[1, :3, :3], batch.K[1])
    K, dist = batch.to_opencv()
    assert K.shape == (2, 3, 3) and dist.shape == (2, 5)
    assert [c["camera_id"] for c in batch.to_colmap()] == [1, 2]


def test_opencv_projection_equals_kornia(cal, points):
    world = points @ cal.R.double()
    K, dist = cal.to_opencv()
    assert K.dtype == np.float64 and K.shape == (3, 3) and dist.shape == (5,) and not dist.any()
    rvec = cv2.Rodrigues(cal.R.double().numpy())[0]
    pixels, _ = cv2.projectPoints(world.numpy(), rvec, np.zeros(3), K, dist)
    kornia_pixels = cal.to(torch.float64).to_kornia().project(world).numpy()
    np.testing.assert_allclose(pixels[:, 0], kornia_pixels, atol=1e-4)  # R is float32: Rodrigues rounds it


def test_to_opencv_is_a_copy(cal):
    K, _ = cal.to_opencv()
    K[0, 0] = -1
    assert float(cal.K[0, 0]) > 0


@pytest.mark.parametrize("model", ["SIMPLE_PINHOLE", "PINHOLE"])
def test_colmap_pixels_are_ours_plus_half_a_pixel(cal, points, model):
    world = points @ cal.R.double()
    camera = cal.to_colmap(model)
    params = camera["params"]
    fx, fy, cx, cy = (params[0], params[0], *params[1:]) if model == "SIMPLE_PINHOLE" else params
    x = world @ cal.R.double().T  # camera frame (COLMAP's camera axes are ours: x right, y down, z forward)
    colmap_pixels = torch.stack([fx * x[:, 0] / x[:, 2] + cx, fy * x[:, 1] / x[:, 2] + cy], 1)
    kornia_pixels = cal.to(torch.float64).to_kornia().project(world)
    assert torch.allclose(colmap_pixels, kornia_pixels + 0.5, atol=1e-4)


def test_convention_colmap_principal_point_at_the_image_centre_is_w_over_2(cal):
    camera = cal.to_colmap()
    # ours: centre of a 320x240 image is (159.5, 119.5); COLMAP's corner origin makes it (160, 120)
    assert float(cal.K[0, 2]) == pytest.approx(159.5) and float(cal.K[1, 2]) == pytest.approx(119.5)
    assert camera["params"][1:] == pytest.approx([160.0, 120.0])


def test_colmap_line_is_a_cameras_txt_line(cal):
    camera = cal.to_colmap("PINHOLE", camera_id=7)
    fields = camera["line"].split()
    assert fields[:4] == ["7", "PINHOLE", "320", "240"]
    assert [float(v) for v in fields[4:]] == camera["params"] and len(camera["params"]) == 4
    assert json.loads(json.dumps(camera)) == camera


def test_unknown_colmap_model_is_named(cal):
    with pytest.raises(ValueError, match="SIMPLE_PINHOLE, PINHOLE"):
        cal.to_colmap("OPENCV")


def test_json_rows_carry_the_principal_point_and_zero_distortion(cal):
    row = json.loads(json.dumps(cal.to_dict()))
    assert row["cx"] == pytest.approx(159.5) and row["cy"] == pytest.approx(119.5)
    assert row["distortion"] == [0.0] * 5
    assert row["cx"] == pytest.approx(row["K"][0][2]) and row["cy"] == pytest.approx(row["K"][1][2])
