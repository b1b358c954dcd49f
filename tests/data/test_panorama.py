import functools
import math

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.data.panorama import (
    crop_ground_truth,
    crop_rays,
    panorama_directions,
    perspective_crops,
    sample_crop_params,
)
from ngp_kornia.geometry.camera import angles_from_rotation, normalize, pitch_roll_from_up

HP, WP = 512, 1024  # 0.35 degree per panorama pixel
SIGMA_DEG = 0.6  # angular half-width of the drawn great circles
# (fov_v, pitch, roll, yaw, (W, H)): landscape and portrait crops, one across the seam
CAMERAS = [
    (60.0, 10.0, 8.0, 30.0, (160, 120)),
    (45.0, -20.0, -15.0, -120.0, (160, 120)),
    (70.0, 25.0, 12.0, 175.0, (96, 128)),
]


@functools.cache
def _directions() -> torch.Tensor:
    return panorama_directions(HP, WP, dtype=torch.float64)


def _great_circles(normals: torch.Tensor, sigma_deg: float = SIGMA_DEG) -> torch.Tensor:
    """(1, 1, HP, WP) float64 panorama, bright on the great circles orthogonal to ``normals`` (n, 3)."""
    d = _directions()
    angle = torch.asin((d @ normalize(normals.double()).T).abs().clamp(max=1.0))  # (HP, WP, n)
    value = torch.exp(-0.5 * (torch.rad2deg(angle) / sigma_deg) ** 2).amax(-1)
    return value[None, None]


def _line_normal(point, direction) -> torch.Tensor:
    """Normal of the plane through the origin containing the 3D line ``point + t * direction``."""
    return torch.linalg.cross(torch.tensor(point, dtype=torch.float64), torch.tensor(direction, dtype=torch.float64))


def _crop(pano, fov, pitch, roll, yaw, size, **kw):
    t = [torch.tensor([v], dtype=torch.float64) for v in (fov, pitch, roll, yaw)]
    return perspective_crops(pano, *t, size=size, **kw)[0, 0]


def _image_line(gt, normal) -> torch.Tensor:
    """Image (a, b, c) of the world plane through the camera centre with the given normal: K^-T R n."""
    return torch.linalg.solve(gt["K"][0].T, gt["R"][0] @ normal)


def _offsets_from_line(image: torch.Tensor, line: torch.Tensor, window: float = 5.0):
    """Per column (or row, for steep lines) intensity-weighted mean signed distance of the band to ``line``.

    Returns the offsets of the stations where the whole band is inside the image and the fraction of the image's
    brightness that lies farther than ``window`` px from the line.
    """
    H, W = image.shape
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    a, b, c = line / line[:2].norm()
    dist = a * x + b * y + c
    near = dist.abs() < window
    weight = image * near
    dim = 0 if abs(b) >= abs(a) else 1  # sum over rows (per column) for flat lines
    station = torch.arange(image.shape[1 - dim], dtype=torch.float64)
    across = -(a * station + c) / b if dim == 0 else -(b * station + c) / a  # where the line crosses the station
    inside = (across >= 2 * window) & (across <= image.shape[dim] - 1 - 2 * window)  # the band is not cut
    mass = weight.sum(dim)
    visible = inside & (mass > 0.5 * mass.max())
    offsets = (weight * dist).sum(dim)[visible] / mass[visible]
    stray = float((image * ~near).sum() / image.sum())
    return offsets, stray


@pytest.mark.parametrize("fov,pitch,roll,yaw,size", CAMERAS)
def test_horizon_circle_lands_on_predicted_horizon(fov, pitch, roll, yaw, size):
    crop = _crop(_great_circles(torch.tensor([[0.0, 1.0, 0.0]])), fov, pitch, roll, yaw, size)
    gt = crop_ground_truth(fov, pitch, roll, yaw, size)
    offsets, stray = _offsets_from_line(crop, gt["horizon"][0])
    assert offsets.numel() > 40
    assert offsets.abs().max() < 0.15
    assert stray < 0.01


@pytest.mark.parametrize("fov,pitch,roll,yaw,size", CAMERAS)
def test_horizontal_3d_lines_stay_straight(fov, pitch, roll, yaw, size):
    """Lines along world x and z map to straight lines, where K and R predict, through their VPs."""
    gt = crop_ground_truth(fov, pitch, roll, yaw, size)
    W, H = size
    rays = crop_rays(gt["fov_v"], gt["pitch"], gt["roll"], gt["yaw"], size)[0]
    for row in (int(0.3 * H), int(0.7 * H)):  # lines above and below the image centre
        for axis, direction in ((0, (1.0, 0.0, 0.0)), (2, (0.0, 0.0, 1.0))):
            point = 3.0 * normalize(rays[row, int(0.4 * W)])  # a point seen at that pixel, 3 m away
            normal = _line_normal(point.tolist(), direction)
            crop = _crop(_great_circles(normal[None]), fov, pitch, roll, yaw, size)
            line = _image_line(gt, normal)
            offsets, stray = _offsets_from_line(crop, line)
            assert offsets.numel() > 20, (row, axis)
            assert offsets.abs().max() < 0.15, (row, axis)
            assert stray < 0.01, (row, axis)
            vp = gt["vps"][0][axis]
            assert abs(float(line @ vp)) / float(line[:2].norm()) < 1e-6 * float(vp.norm())  # the line meets its VP


@pytest.mark.parametrize("fov,pitch,roll,yaw,size", CAMERAS)
def test_meridians_point_at_zenith(fov, pitch, roll, yaw, size):
    """Vertical 3D lines (meridians of the panorama, here edges between sectors of longitude): the LSD segments
    of the crop aim at the predicted zenith."""
    d = _directions()
    lon = torch.atan2(d[..., 0], d[..., 2])
    pano = 0.5 + 0.4 * torch.tanh(torch.sin(6 * lon) / 0.05)  # steps exactly on the meridians every 30 degrees
    crop = _crop(pano[None, None], fov, pitch, roll, yaw, size)
    gray = (crop.clamp(0, 1) * 255).round().to(torch.uint8).numpy()
    segments = cv2.createLineSegmentDetector().detect(gray)[0].reshape(-1, 4)
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    segments = torch.from_numpy(segments[lengths > 0.3 * min(size)]).double()
    assert len(segments) >= 2
    zenith = crop_ground_truth(fov, pitch, roll, yaw, size)["zenith"][0]
    mid = (segments[:, :2] + segments[:, 2:]) / 2
    to_zenith = zenith[:2] - mid * zenith[2]  # direction from the midpoint to the zenith (homogeneous-safe)
    seg = segments[:, 2:] - segments[:, :2]
    cos = (seg * to_zenith).sum(-1).abs() / (seg.norm(dim=-1) * to_zenith.norm(dim=-1))
    assert torch.rad2deg(torch.acos(cos.clamp(max=1.0))).max() < 1.0


@pytest.mark.parametrize("size", [(40, 30), (24, 36)])
def test_rays_match_ground_truth_camera(size):
    """A panorama storing each pixel's own direction crops to the normalised rays R^T K^-1 p."""
    pano = panorama_directions(HP // 2, WP // 2, dtype=torch.float64).permute(2, 0, 1)[None]
    p = sample_crop_params(3, torch.Generator().manual_seed(1), dtype=torch.float64)
    crops = perspective_crops(pano, p["fov_v"], p["pitch"], p["roll"], p["yaw"], size=size)
    assert crops.shape == (3, 3, size[1], size[0])
    gt = crop_ground_truth(p["fov_v"], p["pitch"], p["roll"], p["yaw"], size)
    x, y = np.meshgrid(np.arange(size[0]), np.arange(size[1]))
    pix = torch.from_numpy(np.stack([x, y, np.ones_like(x)], -1)).double()  # (H, W, 3)
    cam = torch.einsum("bij,hwj->bhwi", torch.linalg.inv(gt["K"]), pix)
    world = normalize(torch.einsum("bji,bhwj->bhwi", gt["R"], cam))
    assert torch.allclose(crops.permute(0, 2, 3, 1), world, atol=2e-4)
    assert torch.allclose(normalize(crop_rays(p["fov_v"], p["pitch"], p["roll"], p["yaw"], size)), world)


def test_level_camera_centre_column_and_up():
    """Conventions: yaw 0 looks at the centre column, the top of the crop is the top of the panorama."""
    pano = torch.zeros(1, 1, 64, 128, dtype=torch.float64)
    pano[..., :, 62:66] = 1.0  # a vertical stripe at longitude 0
    pano[..., :8, :] = 2.0  # the sky cap
    crop = _crop(pano, 90.0, 0.0, 0.0, 0.0, (33, 33))
    assert crop[16, 16] == 1.0 and crop[16, 0] == 0.0
    crop_up = _crop(pano, 90.0, 60.0, 0.0, 0.0, (33, 33))  # pitch > 0 looks up: the cap enters from the top
    assert crop_up[0, 16] == 2.0 and crop_up[-1, 16] == 1.0
    crop_right = _crop(pano, 90.0, 0.0, 0.0, 30.0, (33, 33))  # yaw > 0 turns right: the stripe moves left
    cols = crop_right[16].nonzero().flatten().double()
    assert cols.mean() < 16


def test_seam_has_no_artefact():
    g = torch.Generator().manual_seed(0)
    pano = torch.rand(1, 3, 64, 128, generator=g, dtype=torch.float64)
    rolled = torch.roll(pano, 64, dims=-1)  # rolled at longitude L = pano at longitude L - 180
    for mode in ("bilinear", "bicubic", "nearest"):
        across = perspective_crops(pano, 70.0, 5.0, 10.0, 180.0, size=(48, 36), mode=mode)
        inside = perspective_crops(rolled, 70.0, 5.0, 10.0, 0.0, size=(48, 36), mode=mode)
        assert torch.allclose(across, inside, atol=1e-6), mode
    a = perspective_crops(pano, 60.0, 0.0, 0.0, torch.tensor([170.0, -100.0]), size=(32, 24))
    b = perspective_crops(pano, 60.0, 0.0, 0.0, torch.tensor([170.0 + 360.0, -100.0 - 360.0]), size=(32, 24))
    assert torch.allclose(a, b, atol=1e-6)


def test_batch_equals_single_crops_and_shared_panorama():
    g = torch.Generator().manual_seed(2)
    panos = torch.rand(3, 3, 32, 64, generator=g)
    p = sample_crop_params(3, g)
    batch = perspective_crops(panos, p["fov_v"], p["pitch"], p["roll"], p["yaw"], size=(20, 16))
    for i in range(3):
        one = perspective_crops(
            panos[i : i + 1], p["fov_v"][i : i + 1], p["pitch"][i], p["roll"][i], p["yaw"][i], size=(20, 16)
        )
        assert torch.allclose(batch[i], one[0], atol=1e-6)
    shared = perspective_crops(panos[:1], p["fov_v"], p["pitch"], p["roll"], p["yaw"], size=(20, 16))
    assert torch.allclose(shared[0], batch[0]) and shared.shape == batch.shape


def test_dtype_and_gradient(dtype):
    pano = torch.rand(1, 2, 16, 32, dtype=dtype, requires_grad=True)
    crops = perspective_crops(pano, torch.tensor([50.0, 60.0]), 0.0, 0.0, torch.tensor([0.0, 179.0]), size=(8, 6))
    assert crops.dtype == dtype and crops.shape == (2, 2, 6, 8)
    crops.sum().backward()
    assert pano.grad is not None and float(pano.grad.abs().sum()) > 0


def test_gradcheck_wrt_panorama():
    pano = torch.rand(1, 1, 4, 8, dtype=torch.float64, requires_grad=True)

    def crop(x):
        return perspective_crops(x, 80.0, 10.0, 5.0, 170.0, size=(4, 3))

    assert torch.autograd.gradcheck(crop, (pano,), fast_mode=True)


def test_sample_crop_params_ranges_and_determinism():
    p = sample_crop_params(2000, torch.Generator().manual_seed(3))
    for name, (lo, hi) in {"fov_v": (40, 80), "pitch": (-30, 40), "roll": (-20, 20), "yaw": (-180, 180)}.items():
        assert p[name].shape == (2000,)
        assert p[name].min() >= lo and p[name].max() <= hi
        assert p[name].min() < lo + 2 and p[name].max() > hi - 2  # spans the range
    q = sample_crop_params(2000, torch.Generator().manual_seed(3))
    assert all(torch.equal(p[k], q[k]) for k in p)
    fixed = sample_crop_params(3, fov_range=(50, 50), pitch_range=(0, 0))
    assert torch.all(fixed["fov_v"] == 50) and torch.all(fixed["pitch"] == 0)
    assert sample_crop_params(0)["roll"].shape == (0,)


def test_crop_ground_truth_consistency():
    fov = torch.tensor([60.0, 45.0], dtype=torch.float64)
    pitch, roll, yaw = (torch.tensor(v, dtype=torch.float64) for v in ([10.0, -20.0], [5.0, -12.0], [30.0, -170.0]))
    gt = crop_ground_truth(fov, pitch, roll, yaw, (96, 128))
    assert gt["K"].shape == (2, 3, 3) and gt["vps"].shape == (2, 3, 3) and gt["horizon"].shape == (2, 3)
    assert torch.allclose(gt["K"][:, :2, 2], torch.tensor([47.5, 63.5], dtype=torch.float64))
    assert torch.allclose(gt["fov_v"], fov)
    half_w = torch.rad2deg(torch.atan(48 / gt["focal"]))
    assert torch.allclose(gt["fov_h"], 2 * half_w)
    p, r, y = angles_from_rotation(gt["R"])
    assert torch.allclose(p, pitch) and torch.allclose(r, roll) and torch.allclose(y, yaw)
    p2, r2 = pitch_roll_from_up(gt["up"])
    assert torch.allclose(p2, pitch) and torch.allclose(r2, roll)
    assert torch.allclose(gt["horizon"][:, :2].norm(dim=-1), torch.ones(2, dtype=torch.float64))
    assert (gt["horizon"][:, 1] >= 0).all()
    assert torch.allclose(gt["zenith"].norm(dim=-1), torch.ones(2, dtype=torch.float64))
    assert torch.allclose((gt["horizon"] * gt["vps"][:, 0]).sum(-1), torch.zeros(2, dtype=torch.float64), atol=1e-9)
    assert gt["image_size"].tolist() == [[128, 96], [128, 96]]
    assert gt["pitch"].dtype == torch.float64 and crop_ground_truth(60.0, 0.0, 0.0, 0.0, (8, 8))["K"].shape == (1, 3, 3)


def test_errors():
    pano = torch.rand(1, 3, 16, 32)
    with pytest.raises(ValueError, match="panorama must be"):
        perspective_crops(pano[0], 60.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="panorama must be"):
        perspective_crops((pano * 255).to(torch.uint8), 60.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="fov_v_deg must lie in"):
        perspective_crops(pano, 180.0, 0.0, 0.0, 0.0, size=(8, 8))
    with pytest.raises(ValueError, match="size must be"):
        perspective_crops(pano, 60.0, 0.0, 0.0, 0.0, size=(8, 0))
    with pytest.raises(ValueError, match="mode must be"):
        perspective_crops(pano, 60.0, 0.0, 0.0, 0.0, mode="area")
    with pytest.raises(ValueError, match="batch sizes do not match"):
        perspective_crops(pano, torch.tensor([60.0, 50.0]), torch.zeros(3), 0.0, 0.0)
    with pytest.raises(ValueError, match="does not match"):
        perspective_crops(torch.rand(2, 3, 16, 32), torch.full((3,), 60.0), 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"\(B,\) tensor"):
        perspective_crops(pano, torch.full((1, 1), 60.0), 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="low <= high"):
        sample_crop_params(2, pitch_range=(10, -10))
    with pytest.raises(ValueError, match="inside"):
        sample_crop_params(2, fov_range=(0, 90))
    with pytest.raises(ValueError, match="non-negative"):
        sample_crop_params(-1)
    with pytest.raises(ValueError, match="fov_v_deg must lie in"):
        crop_ground_truth(0.0, 0.0, 0.0, 0.0, (8, 8))
    assert math.isfinite(float(perspective_crops(pano, 60.0, 90.0, 0.0, 0.0, size=(8, 8)).sum()))  # at the pole
