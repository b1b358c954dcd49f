"""The parser pipeline on exact synthetic segments: it must recover the camera that projected them."""

import pytest
import torch

from ngp_kornia.geometry import image_center, intrinsics_matrix, rotation_from_angles
from ngp_kornia.pipeline import NeuralGeometricParser


def manhattan_segments(pitch, roll, yaw, fov_v=55.0, size=(480, 640), n=40, seed=0):
    """Segments of 3D lines along the three world axes, projected by a known camera and clipped to the image."""
    g = torch.Generator().manual_seed(seed)
    h, w = size
    f = torch.tensor([h / 2 / torch.tan(torch.deg2rad(torch.tensor(fov_v / 2)))], dtype=torch.float64)
    K = intrinsics_matrix(f, image_center(h, w).double())[0]
    R = rotation_from_angles(*(torch.tensor([a], dtype=torch.float64) for a in (pitch, roll, yaw)))[0]
    segs = []
    for axis in range(3):
        start = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([16.0, 8.0, 16.0])
        start[:, 2] += 14.0  # in front of the camera
        end = start.clone()
        end[:, axis] += 1.5 + 2.0 * torch.rand(n, generator=g, dtype=torch.float64)
        for a, b in zip(start, end, strict=True):
            pa, pb = K @ R @ a, K @ R @ b
            if pa[2] <= 0 or pb[2] <= 0:
                continue
            pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
            inside = all(0 <= p[0] < w and 0 <= p[1] < h for p in (pa, pb))
            if inside and (pa - pb).norm() > 15:
                segs.append(torch.stack([pa, pb]))
    seg = torch.stack(segs)[None].float()
    return seg, torch.ones(seg.shape[:2], dtype=torch.bool), float(f), (h, w)


@pytest.mark.parametrize(("pitch", "roll", "yaw"), [(0.0, 0.0, 30.0), (15.0, -8.0, 20.0), (-20.0, 12.0, -35.0)])
def test_recovers_the_camera_from_exact_segments(pitch, roll, yaw):
    seg, mask, focal, (h, w) = manhattan_segments(pitch, roll, yaw)
    out = NeuralGeometricParser()(torch.zeros(1, 3, h, w), seg, mask)
    assert bool(out.valid[0])
    assert float(out.pitch[0]) == pytest.approx(pitch, abs=0.3)
    assert float(out.roll[0]) == pytest.approx(roll, abs=0.3)
    assert float(out.focal[0]) == pytest.approx(focal, rel=0.03)
    # yaw is defined up to the Manhattan frame's 90 degree symmetry
    assert (float(out.yaw[0]) - yaw + 45) % 90 - 45 == pytest.approx(0.0, abs=0.5)


def test_batch_with_different_line_counts_matches_single_images():
    a, ma, _, (h, w) = manhattan_segments(10.0, 5.0, 25.0, seed=1)
    b, mb, _, _ = manhattan_segments(-5.0, -3.0, -20.0, seed=2, n=25)
    n = max(a.shape[1], b.shape[1])
    seg = torch.zeros(2, n, 2, 2)
    mask = torch.zeros(2, n, dtype=torch.bool)
    seg[0, : a.shape[1]], mask[0, : a.shape[1]] = a[0], True
    seg[1, : b.shape[1]], mask[1, : b.shape[1]] = b[0], True
    parser = NeuralGeometricParser()
    both = parser(torch.zeros(2, 3, h, w), seg, mask)
    first = parser(torch.zeros(1, 3, h, w), a, ma)
    assert float(both.pitch[0]) == pytest.approx(10.0, abs=0.3) and float(both.pitch[1]) == pytest.approx(-5.0, abs=0.3)
    assert float(both.roll[1]) == pytest.approx(-3.0, abs=0.3)
    assert float(first.pitch[0]) == pytest.approx(float(both.pitch[0]), abs=0.3)


def test_deterministic_under_a_seed():
    seg, mask, _, (h, w) = manhattan_segments(5.0, 2.0, 10.0)
    parser = NeuralGeometricParser()
    x = torch.zeros(1, 3, h, w)
    assert torch.equal(parser(x, seg, mask, seed=4).K, parser(x, seg, mask, seed=4).K)


def test_float64_in_float64_out():
    seg, mask, _, (h, w) = manhattan_segments(5.0, 2.0, 10.0)
    out = NeuralGeometricParser()(torch.zeros(1, 3, h, w, dtype=torch.float64), seg.double(), mask)
    assert out.K.dtype == torch.float64 and out.R.dtype == torch.float64


def test_segments_without_mask_is_an_error():
    seg, _, _, (h, w) = manhattan_segments(5.0, 2.0, 10.0)
    with pytest.raises(ValueError, match="mask"):
        NeuralGeometricParser()(torch.zeros(1, 3, h, w), seg)


def test_only_vertical_lines_gives_a_defined_result():
    seg, mask, _, (h, w) = manhattan_segments(5.0, 2.0, 10.0)
    vertical = (seg[0, :, 1] - seg[0, :, 0]).abs()
    keep = vertical[:, 1] > 3 * vertical[:, 0]
    out = NeuralGeometricParser()(torch.zeros(1, 3, h, w), seg[:, keep], mask[:, keep])
    for t in (out.K, out.R, out.horizon, out.zenith, out.vps):
        assert bool(torch.isfinite(t).all())
