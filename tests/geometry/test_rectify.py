"""Tests of ngp_kornia.geometry.rectify: level / upright / frontal homographies and the warping frame."""

import cv2
import numpy as np
import pytest
import torch
from kornia.core.exceptions import BaseError, ShapeError
from torch.autograd import gradcheck

from ngp_kornia.geometry.camera import (
    horizon_border_points,
    horizon_from_zenith,
    intrinsics_matrix,
    rotation_from_angles,
)
from ngp_kornia.geometry.rectify import frontal_homography, level_homography, rectify, upright_homography
from ngp_kornia.training.synth.render import render_scene
from tests.synthetic_camera import BATCHES, H, W, camera_from_angles


def _camera(b, seed=0, dtype=torch.float64):
    """Random hand-held cameras: pitch in [-30, 30], roll in [-20, 20], yaw in [-40, 40], focal in [300, 900]."""
    g = torch.Generator().manual_seed(seed)
    pitch, roll, yaw = (torch.rand(b, generator=g, dtype=torch.float64) * 2 - 1) * torch.tensor(
        [[30.0], [20.0], [40.0]]
    )
    focal = 300 + 600 * torch.rand(b, generator=g, dtype=torch.float64)
    K, R = camera_from_angles(pitch, roll, yaw, focal)
    return K.to(dtype), R.to(dtype), pitch, roll


def _apply(Hm, p):
    """Homogeneous points (B, N, 3) through (B, 3, 3)."""
    return p @ Hm.transpose(-1, -2)


@pytest.mark.parametrize("b", BATCHES)
def test_level_makes_the_true_horizon_horizontal_and_keeps_the_pitch(b):
    K, R, pitch, _ = _camera(b, seed=1)
    Hm = level_homography(K, R)
    up = -R[:, :, 1]
    # two points of the horizon: images of two horizontal directions in front of the camera
    ez = torch.tensor([0.0, 0.0, 1.0], dtype=R.dtype).expand(b, 3)
    ahead = ez - (up * ez).sum(-1, keepdim=True) * up
    side = torch.linalg.cross(up, ahead)
    pts = torch.stack([(K @ (ahead + t * side)[..., None])[..., 0] for t in (-0.3, 0.4)], 1)
    mapped = _apply(Hm, pts)
    y = mapped[..., 1] / mapped[..., 2]
    torch.testing.assert_close(y[:, 0], y[:, 1], atol=1e-6, rtol=0)
    # the zenith stays on the vertical through the principal point: only the roll was removed
    z = _apply(Hm, (K @ up[..., None]).transpose(-1, -2))[:, 0]
    torch.testing.assert_close(z[:, 0], K[:, 0, 2] * z[:, 2], atol=1e-6, rtol=0)


@pytest.mark.parametrize("roll", [-15.0, 5.0, 20.0])
def test_level_horizon_from_border_points(roll):
    """The horizon's border points (camera module) land on one image row after levelling."""
    K, _, _, _ = _camera(1)
    R = rotation_from_angles(torch.tensor([12.0]), torch.tensor([roll])).double()
    pts = horizon_border_points(horizon_from_zenith(K, (K @ -R[:, :, 1:2])[..., 0]), W)
    mapped = _apply(level_homography(K, R), torch.cat([pts, torch.ones_like(pts[..., :1])], -1))
    y = mapped[..., 1] / mapped[..., 2]
    assert abs(float(y[0, 0] - y[0, 1])) < 1e-6
    assert abs(float(pts[0, 0, 1] - pts[0, 1, 1])) > 10  # it was tilted before


@pytest.mark.parametrize("b", BATCHES)
def test_upright_sends_the_vertical_vp_to_infinity_along_y(b):
    K, R, _, _ = _camera(b, seed=2)
    z = _apply(upright_homography(K, R), (K @ -R[:, :, 1:2]).transpose(-1, -2))[:, 0]
    z = z / z.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(z[:, 0], torch.zeros(b, dtype=z.dtype), atol=1e-9, rtol=0)
    torch.testing.assert_close(z[:, 2], torch.zeros(b, dtype=z.dtype), atol=1e-9, rtol=0)
    assert bool((z[:, 1] < 0).all())  # up is still up


def test_upright_keeps_the_yaw():
    K, R, _, _ = _camera(3, seed=3)
    Q = torch.linalg.inv(K) @ upright_homography(K, R) @ K
    R_new = Q @ R  # the virtual camera: a pure yaw
    torch.testing.assert_close(
        R_new[:, 1], torch.tensor([0.0, 1.0, 0.0], dtype=R.dtype).expand(3, 3), atol=1e-9, rtol=0
    )
    torch.testing.assert_close(R_new @ R_new.transpose(-1, -2), torch.eye(3, dtype=R.dtype).expand(3, 3, 3))


@pytest.mark.parametrize("axis", [0, 2])
@pytest.mark.parametrize("b", BATCHES)
def test_frontal_sends_the_facade_horizontal_vp_to_infinity(axis, b):
    K, R, _, _ = _camera(b, seed=4)
    Hm = frontal_homography(K, R, axis)
    other = 2 - axis
    v = _apply(Hm, (K @ R[:, :, other : other + 1]).transpose(-1, -2))[:, 0]
    v = v / v.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(v[:, 1:], torch.zeros(b, 2, dtype=v.dtype), atol=1e-9, rtol=0)
    # the VP of the viewing axis lands on the principal point and the vertical stays vertical
    f = _apply(Hm, (K @ R[:, :, axis : axis + 1]).transpose(-1, -2))[:, 0]
    torch.testing.assert_close(f[:, :2] / f[:, 2:], K[:, :2, 2])
    z = _apply(Hm, (K @ R[:, :, 1:2]).transpose(-1, -2))[:, 0]
    torch.testing.assert_close(z[:, [0, 2]] / z.norm(dim=-1, keepdim=True), torch.zeros(b, 2, dtype=z.dtype))


def test_frontal_faces_the_camera():
    """The sign of the viewing axis follows the optical axis: a small turn, not a half turn."""
    K, _, _, _ = _camera(1)
    R = rotation_from_angles(torch.tensor([5.0]), torch.tensor([3.0]), torch.tensor([170.0])).double()
    Q = torch.linalg.inv(K) @ frontal_homography(K, R, 2) @ K
    assert float(Q[0, 2, 2]) > 0.9


def test_zero_roll_zero_pitch_is_the_identity_for_level_and_upright():
    K, _, _, _ = _camera(3)
    R = rotation_from_angles(torch.zeros(3), torch.zeros(3), torch.tensor([-30.0, 0.0, 25.0])).double()
    eye = torch.eye(3, dtype=K.dtype).expand(3, 3, 3)
    torch.testing.assert_close(level_homography(K, R), eye)
    torch.testing.assert_close(upright_homography(K, R), eye)


def test_dtype_and_shape_are_kept(dtype):
    K, R, _, _ = _camera(2, dtype=dtype)
    for Hm in (level_homography(K, R), upright_homography(K, R), frontal_homography(K, R, 0)):
        assert Hm.dtype == dtype and Hm.shape == (2, 3, 3)
    out, applied = rectify(torch.rand(2, 3, 48, 64, dtype=dtype), upright_homography(K, R))
    assert out.dtype == dtype and applied.dtype == dtype


def test_gradcheck_of_the_homographies():
    K, R, _, _ = _camera(2, seed=5)
    K.requires_grad_(True)
    R.requires_grad_(True)
    assert gradcheck(level_homography, (K, R))
    assert gradcheck(upright_homography, (K, R))
    assert gradcheck(lambda k, r: frontal_homography(k, r, 2), (K, R))


def test_rectify_is_differentiable():
    K, R, _, _ = _camera(1, seed=6)
    img = torch.rand(1, 1, 12, 16, dtype=torch.float64)
    Kr = (K * torch.tensor([[[16 / W], [12 / H], [1.0]]], dtype=K.dtype)).requires_grad_(True)
    out, _ = rectify(img, upright_homography(Kr, R))
    out.sum().backward()
    assert torch.isfinite(Kr.grad).all() and Kr.grad.abs().sum() > 0


def test_bad_inputs_raise():
    K, R, _, _ = _camera(1)
    with pytest.raises(ShapeError):
        level_homography(K[0], R[0])
    with pytest.raises(BaseError):
        frontal_homography(K, R, axis=1)
    with pytest.raises(ValueError, match="crop"):
        rectify(torch.rand(1, 3, 8, 8), torch.eye(3)[None], crop="full")
    with pytest.raises(BaseError):
        rectify(torch.zeros(1, 3, 8, 8, dtype=torch.uint8), torch.eye(3)[None])


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("crop", ["keep", "valid"])
def test_rectify_output_shapes(b, crop):
    K, R, _, _ = _camera(b, seed=7)
    scale = torch.tensor([[[0.1], [0.1], [1.0]]], dtype=K.dtype)  # the same cameras on a 64x48 image
    Hm = upright_homography(K * scale, R)
    img = torch.rand(b, 3, 48, 64, dtype=torch.float64)
    out, applied = rectify(img, Hm, crop=crop)
    assert out.shape[:2] == (b, 3) and applied.shape == (b, 3, 3)
    if crop == "keep":  # every warped corner lies inside the output
        c = torch.tensor([[-0.5, -0.5, 1], [63.5, -0.5, 1], [63.5, 47.5, 1], [-0.5, 47.5, 1]], dtype=K.dtype)
        p = _apply(applied, c.expand(b, 4, 3))
        p = p[..., :2] / p[..., 2:]
        assert bool((p >= -0.5 - 1e-6).all()) and bool((p[..., 0] <= out.shape[-1] - 0.5 + 1e-6).all())
        assert bool((p[..., 1] <= out.shape[-2] - 0.5 + 1e-6).all())
        assert out.shape[-1] * out.shape[-2] <= 4 * 48 * 64
    else:  # only valid pixels: a constant image stays constant everywhere, and the input aspect is kept
        ones, _ = rectify(torch.ones(b, 1, 48, 64, dtype=torch.float64), Hm, crop=crop)
        torch.testing.assert_close(ones, torch.ones_like(ones))
        assert abs(out.shape[-1] / out.shape[-2] - 64 / 48) < 0.1
    sized, _ = rectify(img, Hm, size=(30, 50), crop=crop)
    assert sized.shape == (b, 3, 30, 50)


def test_rectify_identity_keeps_the_image():
    img = torch.rand(2, 3, 24, 32, dtype=torch.float64)
    for crop in ("keep", "valid"):
        out, applied = rectify(img, torch.eye(3, dtype=img.dtype).repeat(2, 1, 1), crop=crop)
        if crop == "keep":
            torch.testing.assert_close(out, img)
            torch.testing.assert_close(applied, torch.eye(3, dtype=img.dtype).expand(2, 3, 3))
        else:
            assert out.shape[-2:] == (23, 30)  # inside the outermost pixel centres (31 x 23), with the 4:3 aspect


def test_keep_refuses_an_extreme_homography():
    K = intrinsics_matrix(torch.tensor([40.0]), torch.tensor([31.5, 23.5]))
    img = torch.rand(1, 3, 48, 64)

    def upright(pitch):  # a wide lens looking far up: the top of the image explodes
        return upright_homography(K, rotation_from_angles(torch.tensor([pitch]), torch.tensor([0.0])))

    with pytest.raises(ValueError, match="input area"):
        rectify(img, upright(50.0), crop="keep")
    with pytest.raises(ValueError, match="infinity"):
        rectify(img, upright(65.0), crop="keep")
    out, _ = rectify(img, upright(50.0), crop="keep", size=(48, 64))
    assert out.shape == (1, 3, 48, 64)
    with pytest.raises(ValueError, match="input area"):
        rectify(img, upright(50.0), crop="valid")
    out, _ = rectify(img, upright(50.0), crop="valid", size=(48, 64))
    assert out.shape == (1, 3, 48, 64)


def _near_vertical_angles(rgb):
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    seg = cv2.createLineSegmentDetector().detect(gray)[0].reshape(-1, 4)
    d = seg[:, 2:] - seg[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    angle = np.degrees(np.arctan2(np.abs(d[:, 0]), np.abs(d[:, 1])))
    return angle[(length > 25) & (angle < 15)]


@pytest.mark.parametrize("seed", [1, 4])
def test_upright_rectification_of_a_rendered_scene_makes_verticals_vertical(seed):
    scene = render_scene(seed, (320, 240))
    img = torch.from_numpy(scene.image).permute(2, 0, 1)[None].float() / 255
    out, _ = rectify(img, upright_homography(scene.K[None], scene.R[None]), crop="valid")
    rgb = (out[0].permute(1, 2, 0) * 255).round().clamp(0, 255).to(torch.uint8).numpy()
    before, after = _near_vertical_angles(scene.image), _near_vertical_angles(rgb)
    assert np.median(before) > 2.0  # the rendered camera was tilted
    assert len(after) >= 5 and np.median(after) < 0.5 and np.quantile(after, 0.9) < 1.0
