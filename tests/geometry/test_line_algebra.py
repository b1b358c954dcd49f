"""Tests of ngp_kornia.geometry.line_algebra: segments, homogeneous lines, intersections (Eq. 2-4), pseudo camera."""

import math

import pytest
import torch
from kornia.core.exceptions import ShapeError
from torch.autograd import gradcheck

from ngp_kornia.geometry.camera import image_center, intrinsics_matrix
from ngp_kornia.geometry.line_algebra import (
    cossim,
    intersect_lines,
    is_near_vertical,
    pseudo_focal,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
)
from tests.synthetic_camera import BATCHES, camera_from_angles

COUNTS = [1, 3, 17]


def _segments(b, n, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    p0 = torch.rand(b, n, 2, generator=g) * 100
    d = torch.randn(b, n, 2, generator=g)
    d = d / d.norm(dim=-1, keepdim=True) * (10 + 30 * torch.rand(b, n, 1, generator=g))
    return torch.stack([p0, p0 + d], -2).to(dtype)


def _segment_at_angle(deg, length=10.0, x0=5.0, y0=7.0):
    a = math.radians(deg)
    return torch.tensor([[x0, y0], [x0 + length * math.cos(a), y0 + length * math.sin(a)]], dtype=torch.float64)


# ---------------------------------------------------------------------------------------------------------------
# segment_lengths


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_segment_lengths(b, n, dtype):
    seg = _segments(b, n, dtype=dtype)
    out = segment_lengths(seg)
    assert out.shape == (b, n) and out.dtype == dtype
    torch.testing.assert_close(out, (seg[..., 1, :] - seg[..., 0, :]).norm(dim=-1))


def test_segment_lengths_known_and_zero():
    seg = torch.tensor([[[[0.0, 0.0], [3.0, 4.0]], [[2.0, 2.0], [2.0, 2.0]]]])
    assert segment_lengths(seg).tolist() == [[5.0, 0.0]]


def test_segment_lengths_zero_length_has_finite_gradient():
    # a zero-length segment (padding, a degenerate detection) must not turn the lengths' gradient into NaN
    seg = torch.tensor([[[[2.0, 2.0], [2.0, 2.0]], [[0.0, 0.0], [3.0, 4.0]]]], dtype=torch.float64, requires_grad=True)
    segment_lengths(seg).sum().backward()
    assert torch.isfinite(seg.grad).all()
    assert torch.equal(seg.grad[0, 0], torch.zeros(2, 2, dtype=torch.float64))
    torch.testing.assert_close(seg.grad[0, 1], torch.tensor([[-0.6, -0.8], [0.6, 0.8]], dtype=torch.float64))


def test_segment_lengths_exception():
    with pytest.raises(ShapeError):
        segment_lengths(torch.zeros(1, 4, 2, 3))


# ---------------------------------------------------------------------------------------------------------------
# segments_to_lines (Eq. 2)


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_segments_to_lines_passes_through_endpoints(b, n, dtype):
    seg = _segments(b, n, seed=b * n, dtype=dtype)
    lines = segments_to_lines(seg)
    assert lines.shape == (b, n, 3) and lines.dtype == dtype
    torch.testing.assert_close(lines[..., :2].norm(dim=-1), torch.ones(b, n, dtype=dtype))
    res = (lines[..., None, :2] * seg).sum(-1) + lines[..., None, 2]  # a x + b y + c at both endpoints
    assert res.abs().max() < (1e-3 if dtype == torch.float32 else 1e-10)


def test_segments_to_lines_known_answers():
    seg = torch.tensor([[[[0.0, 2.0], [5.0, 2.0]], [[3.0, 0.0], [3.0, 9.0]], [[0.0, 0.0], [1.0, 1.0]]]])
    lines = segments_to_lines(seg)
    s = math.sqrt(0.5)
    torch.testing.assert_close(lines[0, 0], torch.tensor([0.0, 1.0, -2.0]))  # y = 2
    torch.testing.assert_close(lines[0, 1], torch.tensor([-1.0, 0.0, 3.0]))  # x = 3
    torch.testing.assert_close(lines[0, 2], torch.tensor([-s, s, 0.0]))  # y = x


@pytest.mark.parametrize("point", [(4.0, 4.0), (0.1, 0.7), (123.456, 78.91)])
def test_segments_to_lines_zero_length(point, dtype):
    # documented: a zero-length segment has no line and gives (0, 0, 0), wherever it lies
    seg = torch.tensor([[[point, point], [[0.0, 0.0], [1.0, 0.0]]]], dtype=dtype)
    lines = segments_to_lines(seg)
    assert torch.isfinite(lines).all()
    torch.testing.assert_close(lines[0, 0], torch.zeros(3, dtype=dtype), atol=1e-6, rtol=0)
    torch.testing.assert_close(lines[0, 1], torch.tensor([0.0, 1.0, 0.0], dtype=dtype))


def test_segments_to_lines_exception():
    with pytest.raises(ShapeError):
        segments_to_lines(torch.zeros(1, 3, 3, 2))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_segments_to_lines_equals_plain_operations(dtype):
    seg = torch.randn(3, 700, 2, 2, generator=torch.Generator().manual_seed(0), dtype=dtype) * 300.0
    seg[:, :5, 1] = seg[:, :5, 0] * 2.0  # lines through the origin
    seg[:, 5:9, 1] = seg[:, 5:9, 0]  # zero length: no line
    p0, p1 = (torch.cat([seg[..., i, :], torch.ones_like(seg[..., :1, 0])], -1) for i in (0, 1))
    cross = torch.linalg.cross(p0, p1)
    expected = cross / cross[..., :2].norm(dim=-1, keepdim=True)
    keep = torch.ones(700, dtype=torch.bool)
    keep[5:9] = False
    # the same lines from the plain operations; reductions may round by an ulp differently per CPU
    torch.testing.assert_close(
        segments_to_lines(seg)[:, keep], expected[:, keep], rtol=8 * torch.finfo(dtype).eps, atol=0.0
    )
    assert (segments_to_lines(seg)[:, 5:9] == 0).all()


def test_segments_to_lines_gradcheck():
    seg = _segments(2, 3).requires_grad_()
    assert gradcheck(segments_to_lines, (seg,))


# ---------------------------------------------------------------------------------------------------------------
# intersect_lines (Eq. 3)


def test_intersect_lines_known_answer():
    v = intersect_lines(torch.tensor([1.0, 0.0, -2.0]), torch.tensor([0.0, 1.0, -3.0]))  # x = 2 and y = 3
    torch.testing.assert_close(v[:2] / v[2], torch.tensor([2.0, 3.0]))
    torch.testing.assert_close(v.norm(), torch.tensor(1.0))


def test_intersect_lines_parallel_at_infinity():
    # y = 2 and y = 5: meet at infinity in the x direction
    v = intersect_lines(torch.tensor([0.0, 1.0, -2.0]), torch.tensor([0.0, 2.0, -10.0]))
    assert v[2] == 0
    torch.testing.assert_close(v.abs(), torch.tensor([1.0, 0.0, 0.0]))
    # parallel segments at 30 degrees: the point at infinity is their direction
    seg = torch.stack([_segment_at_angle(30.0, y0=0.0), _segment_at_angle(30.0, y0=10.0)])[None]
    ln = segments_to_lines(seg)
    v = intersect_lines(ln[:, 0], ln[:, 1])[0]
    assert abs(v[2]) < 1e-12
    torch.testing.assert_close(v[:2].abs(), torch.tensor([math.cos(math.radians(30)), 0.5], dtype=torch.float64))


@pytest.mark.parametrize("scale", [1.0, -2.0])
def test_intersect_lines_identical_gives_zero(scale, dtype):
    # documented: identical lines give (0, 0, 0); both a small line and a pixel-scale line from a segment
    small = torch.tensor([0.3, 0.7, -2.0], dtype=dtype)
    pixel = segments_to_lines(torch.tensor([[100.3, 200.7], [400.1, 250.9]], dtype=dtype))
    lines = torch.stack([small, pixel])
    v = intersect_lines(lines, scale * lines)
    assert torch.isfinite(v).all()
    torch.testing.assert_close(v, torch.zeros(2, 3, dtype=dtype), atol=1e-6, rtol=0)


@pytest.mark.parametrize("b", BATCHES)
def test_intersect_lines_recovers_vp_of_parallel_3d_lines(b, dtype):
    # synthetic camera; project parallel 3D lines along each world axis: their images meet at K @ R[:, i]
    g = torch.Generator().manual_seed(b)
    pitch = (10 + 10 * torch.rand(b, generator=g)).double()
    roll = ((torch.rand(b, generator=g) - 0.5) * 20).double()
    yaw = (20 + 10 * torch.rand(b, generator=g)).double()
    focal = (400 + 200 * torch.rand(b, generator=g)).double()
    K, R = camera_from_angles(pitch, roll, yaw, focal, 480, 640)
    base = torch.tensor([[-2.0, -1.0, 8.0], [1.5, 0.5, 9.0], [0.0, 2.0, 12.0], [2.0, -2.0, 10.0]], dtype=torch.float64)
    for axis in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[axis] = 1.5
        X = torch.stack([base, base + e], -2).expand(b, 4, 2, 3)
        x = torch.einsum("bij,bnkj->bnki", K @ R, X)
        seg = (x[..., :2] / x[..., 2:]).to(dtype)
        lines = segments_to_lines(seg)
        v = intersect_lines(lines[:, :, None], lines[:, None, :])  # all pairs (B, 4, 4, 3)
        assert v.dtype == dtype and v.shape == (b, 4, 4, 3)
        true = (K @ R)[:, :, axis].to(dtype)
        off = ~torch.eye(4, dtype=torch.bool)
        cos = cossim(v, true[:, None, None])[:, off]
        assert cos.min() > (1 - 1e-4 if dtype == torch.float32 else 1 - 1e-10)


def test_intersect_lines_broadcast_and_exception():
    l0 = torch.randn(2, 5, 3)
    l1 = torch.randn(1, 5, 3)
    assert intersect_lines(l0, l1).shape == (2, 5, 3)
    with pytest.raises(ShapeError):
        intersect_lines(torch.zeros(2, 2), torch.zeros(2, 3))
    with pytest.raises(ShapeError):
        intersect_lines(torch.zeros(2, 3), torch.zeros(2, 4))


def test_intersect_lines_gradcheck():
    lines = segments_to_lines(_segments(2, 4, seed=3))
    l0, l1 = lines[:, :2].clone().requires_grad_(), lines[:, 2:].clone().requires_grad_()
    assert gradcheck(intersect_lines, (l0, l1))


# ---------------------------------------------------------------------------------------------------------------
# is_near_vertical (Eq. 4)


@pytest.mark.parametrize(
    ("deg", "expected"),
    [
        (0.0, False),
        (45.0, False),
        (67.0, False),
        (68.0, True),
        (90.0, True),
        (112.0, True),  # 68 degrees the other way
        (113.0, False),
        (-68.0, True),
        (-67.0, False),
        (180.0, False),
    ],
)
def test_is_near_vertical_threshold(deg, expected):
    lines = segments_to_lines(_segment_at_angle(deg)[None, None])
    assert is_near_vertical(lines).item() is expected
    # sign and scale of the homogeneous line do not matter
    assert is_near_vertical(-3 * lines).item() is expected


def test_is_near_vertical_custom_threshold_and_zero_line():
    lines = segments_to_lines(_segment_at_angle(50.0)[None, None])
    assert not is_near_vertical(lines).item()
    assert is_near_vertical(lines, threshold_deg=45.0).item()
    assert not is_near_vertical(torch.zeros(1, 3)).item()  # a zero-length segment's line is not vertical


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_is_near_vertical_cardinality(b, n):
    out = is_near_vertical(segments_to_lines(_segments(b, n)))
    assert out.shape == (b, n) and out.dtype == torch.bool
    with pytest.raises(ShapeError):
        is_near_vertical(torch.zeros(b, n, 2))


# ---------------------------------------------------------------------------------------------------------------
# cossim (Eq. 8)


def test_cossim_sign_and_scale_invariance(dtype):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(5, 7, 3, generator=g).to(dtype)
    y = torch.randn(5, 7, 3, generator=g).to(dtype)
    c = cossim(x, y)
    assert c.shape == (5, 7) and c.dtype == dtype
    assert ((c >= 0) & (c <= 1)).all()
    torch.testing.assert_close(cossim(-x, y), c)
    torch.testing.assert_close(cossim(x, -2.5 * y), c)
    torch.testing.assert_close(cossim(x, x), torch.ones(5, 7, dtype=dtype))


def test_cossim_known_answers():
    assert cossim(torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 3, 0])).item() == 0.0
    assert cossim(torch.tensor([1.0, 1, 0]), torch.tensor([-2.0, 0, 0])).item() == pytest.approx(math.sqrt(0.5))
    assert cossim(torch.zeros(3), torch.tensor([1.0, 2, 3])).item() == 0.0  # zero vector
    out = cossim(torch.randn(4, 1, 3), torch.randn(1, 6, 3))  # broadcast
    assert out.shape == (4, 6)


def test_cossim_exception():
    with pytest.raises(ShapeError):
        cossim(torch.zeros(2, 2), torch.zeros(2, 3))


def test_cossim_gradcheck():
    g = torch.Generator().manual_seed(1)
    x = torch.randn(2, 4, 3, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.randn(2, 4, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert gradcheck(cossim, (x, y))


# ---------------------------------------------------------------------------------------------------------------
# pseudo camera


def test_pseudo_focal():
    assert pseudo_focal(480, 640) == 320.0
    assert pseudo_focal(640, 480) == 320.0  # half the long side, landscape or portrait
    assert pseudo_focal(100, 100) == 50.0


def test_to_pseudo_camera(dtype):
    pts = torch.tensor([[319.5, 239.5], [639.5, 239.5], [-0.5, 239.5], [319.5, -0.5]], dtype=dtype)
    out = to_pseudo_camera(pts, 480, 640)
    assert out.dtype == dtype
    expected = torch.tensor([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, -0.75]], dtype=dtype)
    torch.testing.assert_close(out, expected)
    # portrait: the long side is the height
    torch.testing.assert_close(
        to_pseudo_camera(torch.tensor([[239.5, 639.5]], dtype=dtype), 640, 480), torch.tensor([[0.0, 1.0]], dtype=dtype)
    )


@pytest.mark.parametrize("size", [(480, 640), (640, 480), (7, 3), (1, 1), (2, 9)])
def test_convention_pseudo_camera_centre_and_unit(size, dtype):
    # the image centre (odd and even sizes alike) goes to the origin, and half the long side to one unit
    height, width = size
    centre = image_center(height, width, like=torch.zeros(1, dtype=dtype))
    assert torch.equal(to_pseudo_camera(centre, height, width), torch.zeros(2, dtype=dtype))
    f = pseudo_focal(height, width)
    corner = to_pseudo_camera(centre + torch.tensor([f, -f], dtype=dtype), height, width)
    torch.testing.assert_close(corner, torch.tensor([1.0, -1.0], dtype=dtype))


@pytest.mark.parametrize("b", BATCHES)
def test_to_pseudo_camera_segments_and_lines(b):
    seg = _segments(b, 6)
    ps = to_pseudo_camera(seg, 480, 640)
    assert ps.shape == seg.shape
    # a line through pseudo-camera points is the pixel line mapped by K_p^T
    Kp = intrinsics_matrix(torch.full((b,), 320.0, dtype=torch.float64), image_center(480, 640))
    lines_px = segments_to_lines(seg)
    lines_ps = segments_to_lines(ps)
    mapped = torch.einsum("bji,bnj->bni", Kp, lines_px)  # K^T l
    torch.testing.assert_close(cossim(mapped, lines_ps), torch.ones(b, 6, dtype=torch.float64))


def test_to_pseudo_camera_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        to_pseudo_camera(torch.zeros(4, 3), 480, 640)
    pts = _segments(1, 3).requires_grad_()
    assert gradcheck(lambda p: to_pseudo_camera(p, 480, 640), (pts,))
    assert gradcheck(segment_lengths, (pts,))
