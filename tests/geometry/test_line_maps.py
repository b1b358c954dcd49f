"""Tests of ngp_kornia.geometry.line_maps: rasterised line maps (Eq. 13), closeness maps (Eq. 15) and the map form of
the Manhattan score (Eq. 21)."""

import pytest
import torch
import torch.nn.functional as F
from kornia.core.exceptions import BaseError, ShapeError
from torch.autograd import gradcheck

from ngp_kornia.geometry.line_algebra import segment_lengths, segments_to_lines
from ngp_kornia.geometry.line_maps import (
    closeness_maps,
    line_map,
    line_map_and_pooled_maps,
    manhattan_score_maps,
    rasterize_segments,
)
from ngp_kornia.geometry.vp import closeness, manhattan_score

BATCHES = [1, 2, 5]


def _seg(*xyxy, dtype=torch.float32):
    return torch.tensor([[[x0, y0], [x1, y1]] for x0, y0, x1, y1 in xyxy], dtype=dtype)


def test_rasterize_segments_known_pixels():
    seg = _seg((2, 3, 8, 3), (1, 0, 1, 5), (4, 5, 7, 8))[None]  # horizontal, vertical, 45-degree diagonal
    values = torch.tensor([[[1.0], [2.0], [3.0]]])
    out = rasterize_segments(seg, torch.ones(1, 3, dtype=torch.bool), values, 10, 12)
    assert out.shape == (1, 1, 10, 12)
    expected = torch.zeros(10, 12)
    expected[3, 2:9] = 1.0
    expected[0:6, 1] = 2.0
    for i in range(4):
        expected[5 + i, 4 + i] = 3.0
    assert torch.equal(out[0, 0], expected)


def test_rasterize_segments_endpoint_order_and_rounding():
    # a segment and its reverse draw the same pixels; endpoints snap to the nearest pixel centre
    a = rasterize_segments(
        _seg((1.2, 2.1, 6.8, 2.3))[None], torch.ones(1, 1, dtype=torch.bool), torch.ones(1, 1, 1), 5, 9
    )
    b = rasterize_segments(
        _seg((6.8, 2.3, 1.2, 2.1))[None], torch.ones(1, 1, dtype=torch.bool), torch.ones(1, 1, 1), 5, 9
    )
    assert torch.equal(a, b)
    expected = torch.zeros(5, 9)
    expected[2, 1:8] = 1.0
    assert torch.equal(a[0, 0], expected)


def test_rasterize_segments_overlap_keeps_max_and_channels():
    seg = _seg((0, 2, 5, 2), (2, 0, 2, 4))[None]
    values = torch.tensor([[[0.3, 0.9], [0.7, 0.1]]])
    out = rasterize_segments(seg, torch.ones(1, 2, dtype=torch.bool), values, 5, 6)
    assert out.shape == (1, 2, 5, 6)
    assert out[0, 0, 2, 2] == pytest.approx(0.7) and out[0, 1, 2, 2] == pytest.approx(0.9)
    assert out[0, 0, 2, 0] == pytest.approx(0.3) and out[0, 1, 0, 2] == pytest.approx(0.1)


def test_rasterize_segments_mask_clipping_and_empty():
    seg = _seg((0, 1, 3, 1), (0, 3, 3, 3))[None]
    out = rasterize_segments(seg, torch.tensor([[True, False]]), torch.ones(1, 2, 1), 5, 4)
    assert out[0, 0, 1].tolist() == [1.0] * 4 and out[0, 0, 3].sum() == 0  # padding not drawn
    # segments partly or fully outside the map: only the inside pixels, no wrap-around onto the borders
    seg = _seg((-5, 1, 2, 1), (10, 10, 20, 10), (1, -3, 1, -1))[None]
    out = rasterize_segments(seg, torch.ones(1, 3, dtype=torch.bool), torch.ones(1, 3, 1), 4, 4)
    expected = torch.zeros(4, 4)
    expected[1, 0:3] = 1.0
    assert torch.equal(out[0, 0], expected)
    # no lines at all: zero maps
    out = rasterize_segments(torch.zeros(2, 0, 2, 2), torch.zeros(2, 0, dtype=torch.bool), torch.zeros(2, 0, 3), 4, 5)
    assert out.shape == (2, 3, 4, 5) and torch.equal(out, torch.zeros(2, 3, 4, 5))
    out = rasterize_segments(torch.rand(2, 3, 2, 2), torch.zeros(2, 3, dtype=torch.bool), torch.ones(2, 3, 1), 4, 5)
    assert torch.equal(out, torch.zeros(2, 1, 4, 5))


def test_rasterize_segments_zero_length_segment():
    out = rasterize_segments(_seg((2, 2, 2, 2))[None], torch.ones(1, 1, dtype=torch.bool), torch.ones(1, 1, 1), 4, 4)
    expected = torch.zeros(4, 4)
    expected[2, 2] = 1.0
    assert torch.equal(out[0, 0], expected)


@pytest.mark.parametrize("b", BATCHES)
def test_rasterize_segments_cardinality(b, dtype):
    g = torch.Generator().manual_seed(b)
    n = 6
    seg = (torch.rand(b, n, 2, 2, generator=g) * 30).to(dtype)
    mask = torch.rand(b, n, generator=g) < 0.7
    values = torch.rand(b, n, 3, generator=g).to(dtype)
    out = rasterize_segments(seg, mask, values, 32, 40)
    assert out.shape == (b, 3, 32, 40) and out.dtype == dtype
    assert ((out >= 0) & (out <= values.max())).all()
    lm = line_map(seg, mask, 32, 40)
    assert lm.shape == (b, 1, 32, 40) and lm.dtype == dtype
    # every drawn pixel is on the line map and vice versa (values are positive)
    assert torch.equal(out.amax(1, keepdim=True) > 0, lm > 0)


def test_rasterize_segments_exceptions():
    seg, mask, values = torch.zeros(1, 2, 2, 2), torch.ones(1, 2, dtype=torch.bool), torch.ones(1, 2, 1)
    with pytest.raises(ShapeError):
        rasterize_segments(seg[0], mask, values, 4, 4)
    with pytest.raises(ShapeError):
        rasterize_segments(seg, mask[0], values, 4, 4)
    with pytest.raises(ShapeError):
        rasterize_segments(seg, mask, values[..., 0], 4, 4)
    with pytest.raises(BaseError, match="map size"):
        rasterize_segments(seg, mask, values, 0, 4)
    with pytest.raises(BaseError, match="map size"):
        rasterize_segments(seg, mask, values, 4, -1)


def test_rasterize_segments_gradcheck_values():
    seg = _seg((0, 1, 6, 1), (2, 3, 2, 7), (4, 4, 7, 7), dtype=torch.float64)[None].expand(2, 3, 2, 2)
    mask = torch.tensor([[True, True, True], [True, False, True]])
    values = torch.rand(2, 3, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64) + 0.1
    values.requires_grad_()
    assert gradcheck(lambda v: rasterize_segments(seg, mask, v, 9, 8), (values,))
    # d(sum of map)/d(value) is the number of pixels the segment covers
    out = rasterize_segments(seg, mask, values, 9, 8)
    (grad,) = torch.autograd.grad(out.sum(), values)
    torch.testing.assert_close(grad[0, :, 0], torch.tensor([7.0, 5.0, 4.0], dtype=torch.float64))
    assert grad[1, 1].abs().sum() == 0  # masked: no gradient


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("cell", [1, 4, 8])
def test_pooled_maps_equal_drawn_maps_averaged(b, dtype, cell):
    g = torch.Generator().manual_seed(b + cell)
    seg = (torch.rand(b, 12, 2, 2, generator=g) * 50 - 5).to(dtype)  # some leave the map
    seg[:, 0] = torch.tensor([[3.0, 4.0], [3.0, 4.0]], dtype=dtype)  # a point
    seg[:, 1] = torch.tensor([[0.0, 9.0], [39.0, 9.0]], dtype=dtype)  # crosses others: overlaps keep the max
    mask = torch.rand(b, 12, generator=g) < 0.8
    values = torch.rand(b, 12, 5, generator=g).to(dtype)
    lines, pooled = line_map_and_pooled_maps(seg, mask, values, 32, 40, cell)
    assert lines.shape == (b, 1, 32, 40) and pooled.shape == (b, 5, 32 // cell, 40 // cell)
    assert lines.dtype == pooled.dtype == dtype
    torch.testing.assert_close(lines, line_map(seg, mask, 32, 40), rtol=0, atol=0)
    torch.testing.assert_close(pooled, F.avg_pool2d(rasterize_segments(seg, mask, values, 32, 40), cell))


def test_pooled_maps_gradients_equal_the_drawn_maps():
    g = torch.Generator().manual_seed(0)
    seg = torch.rand(2, 8, 2, 2, generator=g, dtype=torch.float64) * 16
    mask = torch.rand(2, 8, generator=g) > 0.2
    values = (torch.rand(2, 8, 3, generator=g, dtype=torch.float64) + 0.1).requires_grad_()
    assert gradcheck(lambda v: line_map_and_pooled_maps(seg, mask, v, 16, 16, 4)[1], (values,))
    weights = torch.rand(2, 3, 4, 4, generator=g, dtype=torch.float64)
    (grad,) = torch.autograd.grad((line_map_and_pooled_maps(seg, mask, values, 16, 16, 4)[1] * weights).sum(), values)
    drawn = F.avg_pool2d(rasterize_segments(seg, mask, values, 16, 16), 4)
    (reference,) = torch.autograd.grad((drawn * weights).sum(), values)
    torch.testing.assert_close(grad, reference)


def test_pooled_maps_empty_and_exceptions():
    seg, values = torch.zeros(1, 2, 2, 2), torch.ones(1, 2, 3)
    lines, pooled = line_map_and_pooled_maps(seg, torch.zeros(1, 2, dtype=torch.bool), values, 8, 8, 4)
    assert not lines.any() and not pooled.any() and pooled.shape == (1, 3, 2, 2)
    with pytest.raises(BaseError, match="not a multiple of 3"):
        line_map_and_pooled_maps(seg, torch.ones(1, 2, dtype=torch.bool), values, 8, 8, 3)
    with pytest.raises(ShapeError):
        line_map_and_pooled_maps(seg, torch.ones(1, 2, dtype=torch.bool), values[0], 8, 8, 4)


def test_line_map_known():
    seg = torch.tensor([[[[1.0, 0.0], [1.0, 2.0]]]])
    out = line_map(seg, torch.tensor([[True]]), 4, 3)[0, 0]
    # both endpoints are drawn, as in rasterize_segments (the docstring example of line_map shows the last row empty;
    # that doctest only passes because of the lenient NUMBER doctest option)
    assert torch.equal(out, torch.tensor([[0.0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 0, 0]]))


def test_closeness_maps_and_exception():
    seg = _seg((0, 1, 4, 1), (2, 3, 4, 3))[None]
    c = torch.tensor([[[0.1, 0.2], [0.5, 0.6], [0.9, 0.3]]])  # (B, 3, N)
    out = closeness_maps(seg, torch.ones(1, 2, dtype=torch.bool), c, 5, 5)
    assert out.shape == (1, 3, 5, 5)
    torch.testing.assert_close(out[0, :, 1, 0], c[0, :, 0])
    torch.testing.assert_close(out[0, :, 3, 3], c[0, :, 1])
    with pytest.raises(ShapeError):
        closeness_maps(seg, torch.ones(1, 2, dtype=torch.bool), c[:, :2], 5, 5)


def test_manhattan_score_maps_known_and_empty():
    L = torch.ones(1, 1, 2, 2)
    A = torch.zeros(1, 3, 2, 2)
    A[0, 1] = 0.5
    A[0, 2, 0, 0] = 0.9
    torch.testing.assert_close(manhattan_score_maps(L, A), torch.tensor([(0.9 + 3 * 0.5) / 4]))
    out = manhattan_score_maps(torch.zeros(2, 1, 4, 4), torch.zeros(2, 3, 4, 4))
    assert torch.equal(out, torch.zeros(2))
    with pytest.raises(ShapeError):
        manhattan_score_maps(torch.zeros(1, 2, 4, 4), torch.zeros(1, 3, 4, 4))
    with pytest.raises(ShapeError):
        manhattan_score_maps(torch.zeros(1, 1, 4, 4), torch.zeros(1, 2, 4, 4))


def _scene(b, dtype):
    """Non-overlapping axis-aligned and diagonal segments in a 64x64 map, and three VPs per image."""
    seg = _seg(
        (3, 3, 40, 3),
        (3, 10, 3, 50),
        (10, 20, 30, 40),
        (50, 5, 50, 60),
        (20, 55, 45, 55),
        (35, 10, 45, 20),
        dtype=dtype,
    )
    seg = seg[None].expand(b, -1, -1, -1).clone()
    g = torch.Generator().manual_seed(b)
    vps = torch.randn(b, 3, 3, generator=g).to(dtype) * torch.tensor([30.0, 30.0, 1.0], dtype=dtype)
    vps[:, :, :2] += 32 * vps[:, :, 2:]
    # make VP 0 lie on segment 0's line so a closeness of 1 appears
    vps[:, 0] = torch.tensor([100.0, 3.0, 1.0], dtype=dtype)
    mask = torch.ones(b, seg.shape[1], dtype=torch.bool)
    if b > 1:
        mask[1, 2] = False
    return seg, mask, vps


@pytest.mark.parametrize("b", BATCHES)
def test_manhattan_score_maps_agrees_with_line_level_score(b, dtype):
    seg, mask, vps = _scene(b, dtype)
    lines = segments_to_lines(seg)
    c = closeness(lines, vps)  # (B, 3, N)
    maps = closeness_maps(seg, mask, c, 64, 64)
    lm = line_map(seg, mask, 64, 64)
    score_maps = manhattan_score_maps(lm, maps)
    assert score_maps.shape == (b,) and score_maps.dtype == dtype
    # exact with each segment weighted by the pixels it covers
    n = seg.shape[1]
    onehot = torch.eye(n, dtype=dtype)[None].expand(b, n, n)
    pixels = rasterize_segments(seg, torch.ones_like(mask), onehot, 64, 64).flatten(2).sum(-1)  # (B, N)
    exact = manhattan_score(c[:, None], pixels, mask)[:, 0]
    torch.testing.assert_close(exact, score_maps, atol=1e-5, rtol=1e-5)
    # close with the Euclidean lengths the line-level score is given in practice
    approx = manhattan_score(c[:, None], segment_lengths(seg), mask)[:, 0]
    torch.testing.assert_close(approx, score_maps, atol=0.03, rtol=0)


def test_manhattan_score_maps_gradcheck():
    seg, mask, vps = _scene(2, torch.float64)
    lines = segments_to_lines(seg)
    lm = line_map(seg, mask, 64, 64)
    vps = vps.requires_grad_()
    assert gradcheck(lambda v: manhattan_score_maps(lm, closeness_maps(seg, mask, closeness(lines, v), 64, 64)), (vps,))


def _reference_pixels(segments, mask, height, width):
    """The drawn pixels as first written: every image's segments sampled on one grid, duplicates removed by sorting."""
    pairs = set()
    for b in range(segments.shape[0]):
        length = (segments[b, :, 1] - segments[b, :, 0]).norm(dim=-1)
        count = int(torch.where(mask[b], length, torch.zeros_like(length)).amax().ceil()) + 2
        t = torch.linspace(0.0, 1.0, count, dtype=segments.dtype)
        for n in mask[b].nonzero().flatten().tolist():
            p0, p1 = segments[b, n, 0], segments[b, n, 1]
            for x, y in (p0 + (p1 - p0) * t[:, None]).round().long().tolist():
                if 0 <= x < width and 0 <= y < height:
                    pairs.add((b, n, y * width + x))
    return pairs


@pytest.mark.parametrize("size", [(16, 16), (9, 13), (5, 1), (1, 7)])
def test_rasterize_segments_equal_reference_sampling(size):
    # segments crossing the border, lying outside, of different lengths per image, with padding
    height, width = size
    g = torch.Generator().manual_seed(height * 31 + width)
    segments = torch.rand(3, 12, 2, 2, generator=g) * torch.tensor([width + 6.0, height + 6.0]) - 3.0
    segments[1] *= 0.3
    mask = torch.rand(3, 12, generator=g) > 0.25
    segments[~mask] = float("nan")  # padding is never sampled
    values = torch.arange(1.0, 37.0).reshape(3, 12, 1)
    out = rasterize_segments(segments, mask, values, height, width).flatten(1)
    expected = torch.zeros(3, height * width)
    for b, n, pix in _reference_pixels(segments, mask, height, width):
        expected[b, pix] = max(float(expected[b, pix]), float(values[b, n, 0]))
    assert torch.equal(out, expected)
    lines, pooled = line_map_and_pooled_maps(segments, mask, values, height, width, 1)
    assert torch.equal(lines.flatten(1), (expected > 0).float())
    assert torch.equal(pooled.flatten(1), expected)


def test_a_segment_thrown_far_out_draws_the_pixels_of_its_part_inside():
    """Undistorting beyond the lens model's reach throws segment ends millions of pixels out: the map holds the
    same pixels as for the segment cut at its border (sampled a few hundred times, not 2e10 times)."""
    far = torch.tensor([[[[-1e10, 20.0], [1e10, 30.0]], [[5.0, 5.0], [50.0, 40.0]]]])
    cut = torch.tensor([[[[-1.0, 24.9999995], [64.0, 25.0000003]], [[5.0, 5.0], [50.0, 40.0]]]])
    mask, values = torch.ones(1, 2, dtype=torch.bool), torch.tensor([[[1.0], [2.0]]])
    assert torch.equal(rasterize_segments(far, mask, values, 48, 64), rasterize_segments(cut, mask, values, 48, 64))
