"""Tests of ngp_kornia.geometry.vp: structure tensors (Eq. 9-10), closeness (Eq. 14), Manhattan score (Eq. 21) and
top-k averaging (Eq. 23)."""

import math

import pytest
import torch
from kornia.core.exceptions import ShapeError
from torch.autograd import gradcheck

from ngp_kornia.geometry.camera import image_center, intrinsics_matrix, normalize, rotation_from_angles
from ngp_kornia.geometry.line_algebra import cossim, pseudo_focal, segment_lengths, segments_to_lines, to_pseudo_camera
from ngp_kornia.geometry.vp import (
    closeness,
    closeness_of,
    dominant_eigenvector,
    line_vp_cosine,
    manhattan_score,
    segment_vp_angle,
    structure_tensor,
    symmetric_dominant_eigenvector,
    topk_weighted_average,
    weighted_structure_tensor,
)
from tests.synthetic_camera import BATCHES, camera_from_angles

COUNTS = [1, 4, 16]


def _randn(*shape, seed=0, dtype=torch.float64):
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed)).to(dtype)


# ---------------------------------------------------------------------------------------------------------------
# structure tensors


def test_structure_tensor_trace_symmetry_sign(dtype):
    v = _randn(3, 7, 3, dtype=dtype)
    st = structure_tensor(v)
    assert st.shape == (3, 7, 3, 3) and st.dtype == dtype
    torch.testing.assert_close(st.diagonal(dim1=-2, dim2=-1).sum(-1), torch.ones(3, 7, dtype=dtype))
    torch.testing.assert_close(st, st.transpose(-1, -2))
    torch.testing.assert_close(structure_tensor(-v), st)  # sign invariance
    torch.testing.assert_close(structure_tensor(4.5 * v), st)  # scale invariance
    # rank one: st @ v = v (v normalised)
    u = normalize(v)
    torch.testing.assert_close((st @ u[..., None])[..., 0], u)


def test_structure_tensor_known_and_zero():
    torch.testing.assert_close(structure_tensor(torch.tensor([0.0, 0.0, -2.0])), torch.diag(torch.tensor([0.0, 0, 1])))
    torch.testing.assert_close(
        structure_tensor(torch.tensor([1.0, 1.0, 0.0])), torch.tensor([[0.5, 0.5, 0], [0.5, 0.5, 0], [0, 0, 0.0]])
    )
    assert torch.equal(structure_tensor(torch.zeros(3)), torch.zeros(3, 3))


def test_structure_tensor_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        structure_tensor(torch.zeros(4, 2))
    v = _randn(2, 3, 3).requires_grad_()
    assert gradcheck(structure_tensor, (v,))


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_weighted_structure_tensor_cardinality(b, n, dtype):
    v = _randn(b, n, 3, dtype=dtype)
    w = torch.rand(b, n, generator=torch.Generator().manual_seed(1)).to(dtype) + 0.1
    st = weighted_structure_tensor(v, w)
    assert st.shape == (b, 3, 3) and st.dtype == dtype
    torch.testing.assert_close(st.diagonal(dim1=-2, dim2=-1).sum(-1), torch.ones(b, dtype=dtype))  # weighted mean
    expected = (w[..., None, None] * structure_tensor(v)).sum(1) / w.sum(1)[:, None, None]
    torch.testing.assert_close(st, expected)
    # invariant to a global scale of the weights and to the sign of each point
    torch.testing.assert_close(weighted_structure_tensor(-v, 7 * w), st)


def test_weighted_structure_tensor_known_and_zero_weights():
    v = torch.tensor([[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]])
    torch.testing.assert_close(
        weighted_structure_tensor(v, torch.tensor([[3.0, 1.0]])), torch.diag(torch.tensor([0.25, 0.75, 0]))[None]
    )
    # zero weights: the zero matrix, finite; a zero-weight point does not count
    assert torch.equal(weighted_structure_tensor(v, torch.zeros(1, 2)), torch.zeros(1, 3, 3))
    torch.testing.assert_close(weighted_structure_tensor(v, torch.tensor([[2.0, 0.0]])), structure_tensor(v[:, 0]))
    # one row empty, another not
    v2 = v.expand(2, 2, 3)
    out = weighted_structure_tensor(v2, torch.tensor([[0.0, 0.0], [1.0, 1.0]]))
    assert torch.equal(out[0], torch.zeros(3, 3))
    torch.testing.assert_close(out[1], torch.diag(torch.tensor([0.5, 0.5, 0])))


def test_weighted_structure_tensor_exception():
    with pytest.raises(ShapeError):
        weighted_structure_tensor(torch.zeros(1, 2, 4), torch.ones(1, 2))
    with pytest.raises(ShapeError):
        weighted_structure_tensor(torch.zeros(1, 2, 3), torch.ones(1, 2, 1))


def test_weighted_structure_tensor_gradcheck():
    v = _randn(2, 5, 3, seed=2).requires_grad_()
    w = (torch.rand(2, 5, generator=torch.Generator().manual_seed(3), dtype=torch.float64) + 0.1).requires_grad_()
    assert gradcheck(weighted_structure_tensor, (v, w))


# ---------------------------------------------------------------------------------------------------------------
# dominant_eigenvector


@pytest.mark.parametrize("b", BATCHES)
def test_dominant_eigenvector_known(b, dtype):
    Q = torch.linalg.qr(_randn(b, 3, 3, seed=b)).Q.to(dtype)
    lam = torch.tensor([0.1, 0.3, 0.6], dtype=dtype)
    T = Q @ torch.diag(lam) @ Q.transpose(-1, -2)
    v = dominant_eigenvector(T)
    assert v.shape == (b, 3) and v.dtype == dtype
    torch.testing.assert_close(v.norm(dim=-1), torch.ones(b, dtype=dtype))
    torch.testing.assert_close(cossim(v, Q[:, :, 2]), torch.ones(b, dtype=dtype))
    # sign convention: the largest-magnitude component is positive
    idx = v.abs().argmax(-1, keepdim=True)
    assert (torch.gather(v, -1, idx) > 0).all()
    torch.testing.assert_close(dominant_eigenvector(T), dominant_eigenvector(2 * T))


def test_dominant_eigenvector_diag_and_fallback():
    torch.testing.assert_close(
        dominant_eigenvector(torch.diag(torch.tensor([0.1, 0.2, 0.7]))[None]), torch.tensor([[0.0, 0, 1]])
    )
    T = torch.stack([torch.zeros(3, 3), torch.diag(torch.tensor([0.9, 0.05, 0.05]))])
    out = dominant_eigenvector(T)
    torch.testing.assert_close(out, torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))  # zero tensor -> (0, 1, 0)
    fb = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(dominant_eigenvector(T, fallback=fb), torch.tensor([[0.0, 0, 1], [1.0, 0, 0]]))
    torch.testing.assert_close(
        dominant_eigenvector(T, fallback=torch.tensor([1.0, 0, 0]))[0], torch.tensor([1.0, 0, 0])
    )


def test_dominant_eigenvector_of_a_non_finite_tensor_is_the_fallback():
    # torch.linalg.eigh fails on NaN entries ("the algorithm failed to converge"): a defined answer instead
    T = torch.stack([torch.full((3, 3), float("nan")), torch.diag(torch.tensor([0.9, 0.05, 0.05]))])
    T[0, 0, 0] = float("inf")
    torch.testing.assert_close(dominant_eigenvector(T), torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    torch.testing.assert_close(symmetric_dominant_eigenvector(T[:1]), torch.tensor([[0.0, 1.0, 0.0]]))


@pytest.mark.parametrize("b", [1, 3])
def test_symmetric_dominant_eigenvector_equals_dominant_eigenvector_bitwise(b, dtype):
    # weighted sums of structure tensors are exactly symmetric: symmetrising them changes no bit
    g = torch.Generator().manual_seed(b)
    v = torch.randn(b, 300, 3, generator=g, dtype=dtype) * torch.rand(b, 300, 1, generator=g, dtype=dtype) ** 4
    w = torch.rand(b, 300, generator=g, dtype=dtype) * (torch.rand(b, 300, generator=g) < 0.5)
    w[0] = 0.0  # an empty tensor: the fallback
    T = weighted_structure_tensor(v, w)
    assert torch.equal(T, T.transpose(-1, -2))
    assert torch.equal(symmetric_dominant_eigenvector(T), dominant_eigenvector(T))
    fb = torch.tensor([1.0, 0.0, 0.0], dtype=dtype)
    assert torch.equal(symmetric_dominant_eigenvector(T, fb), dominant_eigenvector(T, fb))


def test_weighted_structure_tensor_recovers_point_from_noisy_samples(dtype):
    g = torch.Generator().manual_seed(7)
    true = normalize(torch.tensor([[0.3, -2.0, 0.8], [1.0, 0.2, 0.05]], dtype=torch.float64))
    n = 200
    noisy = true[:, None] + 0.03 * torch.randn(2, n, 3, generator=g, dtype=torch.float64)
    # random homogeneous scale and sign: the tensor averages points, not vectors
    scale = (torch.rand(2, n, 1, generator=g, dtype=torch.float64) + 0.2) * torch.where(
        torch.rand(2, n, 1, generator=g) < 0.5, -1.0, 1.0
    ).double()
    samples = noisy * scale
    # low-weight outliers
    samples[:, :20] = torch.randn(2, 20, 3, generator=g, dtype=torch.float64)
    w = torch.ones(2, n, dtype=torch.float64)
    w[:, :20] = 0.01
    st = weighted_structure_tensor(samples.to(dtype), w.to(dtype))
    v = dominant_eigenvector(st)
    assert v.dtype == dtype
    assert (cossim(v, true.to(dtype)) > 0.999).all()
    # zero weights on the inliers and the outliers dominate: the estimate is then wrong, so the weights matter
    w_bad = torch.zeros(2, n, dtype=dtype)
    w_bad[:, :20] = 1.0
    v_bad = dominant_eigenvector(weighted_structure_tensor(samples.to(dtype), w_bad))
    assert (cossim(v_bad, true.to(dtype)) < 0.99).any()


def test_dominant_eigenvector_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        dominant_eigenvector(torch.zeros(3, 3))
    Q = torch.linalg.qr(_randn(2, 3, 3, seed=11)).Q
    T = (Q @ torch.diag(torch.tensor([0.1, 0.3, 0.6], dtype=torch.float64)) @ Q.transpose(-1, -2)).requires_grad_()
    assert gradcheck(dominant_eigenvector, (T,))
    v = _randn(1, 6, 3, seed=12).requires_grad_()
    w = torch.linspace(0.2, 1.0, 6, dtype=torch.float64)[None].requires_grad_()
    assert gradcheck(lambda a, b: dominant_eigenvector(weighted_structure_tensor(a, b)), (v, w))


# ---------------------------------------------------------------------------------------------------------------
# line_vp_cosine, closeness (Eq. 14 and the sharp kernel)


def _lines_through(vp_xy, angles_deg, dtype=torch.float64):
    """Segments whose lines pass exactly through vp_xy, at the given angles: (1, N, 2, 2)."""
    seg = []
    for a in angles_deg:
        d = torch.tensor([math.cos(math.radians(a)), math.sin(math.radians(a))], dtype=torch.float64)
        p0 = torch.tensor(vp_xy, dtype=torch.float64) + 50 * d
        seg.append(torch.stack([p0, p0 + 20 * d]))
    return torch.stack(seg)[None].to(dtype)


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_line_vp_cosine_and_closeness_shapes(b, n, dtype):
    lines = _randn(b, n, 3, seed=1, dtype=dtype)
    vps = _randn(b, 2, 3, 3, seed=2, dtype=dtype)
    cos = line_vp_cosine(lines, vps)
    assert cos.shape == (b, 2, 3, n) and cos.dtype == dtype
    assert ((cos >= 0) & (cos <= 1 + 1e-6)).all()
    torch.testing.assert_close(cos[:, 1, 2], cossim(lines, vps[:, 1, 2, None]))
    c = closeness(lines, vps)
    torch.testing.assert_close(c, 1 - cos)
    s = closeness(lines, vps, 89.0)
    assert s.shape == (b, 2, 3, n) and s.dtype == dtype
    assert ((s >= 0) & (s <= 1)).all()  # (0, 1] mathematically; exp underflows to 0 far from the VP
    # a single VP per batch: (B, 3) -> (B, N)
    assert closeness(lines, vps[:, 0, 0]).shape == (b, n)


def test_closeness_known_answers():
    vp = (400.0, -300.0)
    seg = _lines_through(vp, [10.0, 80.0, 135.0])
    lines = segments_to_lines(seg)
    v = torch.tensor([[vp[0], vp[1], 1.0]], dtype=torch.float64)
    torch.testing.assert_close(closeness(lines, v), torch.ones(1, 3, dtype=torch.float64))
    torch.testing.assert_close(closeness(lines, v, 89.0), torch.ones(1, 3, dtype=torch.float64))
    torch.testing.assert_close(line_vp_cosine(lines, -5 * v), torch.zeros(1, 3, dtype=torch.float64))
    # a point at infinity: lines parallel to its direction pass through it
    seg = torch.tensor([[[[0.0, 0.0], [1.0, 1.0]], [[5.0, 0.0], [7.0, 2.0]], [[0.0, 0.0], [1.0, 0.0]]]])
    c = closeness(segments_to_lines(seg), torch.tensor([[1.0, 1.0, 0.0]]))
    torch.testing.assert_close(c[0, :2], torch.ones(2))
    assert c[0, 2] < 0.5
    # a line orthogonal (as a vector) to the VP: closeness 0
    torch.testing.assert_close(
        closeness(torch.tensor([[[1.0, 0.0, 0.0]]]), torch.tensor([[1.0, 0.0, 0.0]])), torch.zeros(1, 1)
    )


@pytest.mark.parametrize("angle_deg", [89.0, 85.0])
def test_sharp_closeness_known_kernel(angle_deg):
    # the line vector at exactly angle_deg to the VP vector: exp(-1/2)
    a = math.radians(angle_deg)
    lines = torch.tensor([[[math.cos(a), math.sin(a), 0.0]]], dtype=torch.float64)
    vp = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(
        closeness(lines, vp, angle_deg), torch.tensor([[math.exp(-0.5)]], dtype=torch.float64)
    )


def test_closeness_of_the_sharp_kernel():
    torch.testing.assert_close(closeness_of(torch.tensor([0.0, 1.0]), 89.0), torch.tensor([1.0, 0.0]))
    # a floor on the exponent keeps the tail a normal float: exp(-30) instead of an underflow to 0
    far = torch.tensor([1.0], dtype=torch.float64)
    exp30 = torch.tensor([math.exp(-30.0)], dtype=torch.float64)
    torch.testing.assert_close(closeness_of(far, 89.0, floor=-30.0), exp30)
    assert float(closeness_of(far, 89.0)) < 1e-300
    c89 = math.cos(math.radians(89.0))
    torch.testing.assert_close(
        closeness_of(torch.tensor([c89], dtype=torch.float64), 89.0),
        torch.tensor([math.exp(-0.5)], dtype=torch.float64),
    )
    # closeness with an angle is the kernel of line_vp_cosine; the best over VPs is the kernel of the smallest cosine
    lines = _randn(2, 6, 3, seed=3)
    vps = normalize(torch.linalg.cross(lines[:, :3], _randn(2, 3, 3, seed=4)))  # VP i lies on line i
    cos = line_vp_cosine(lines, vps)
    torch.testing.assert_close(closeness(lines, vps, 85.0), closeness_of(cos, 85.0))
    torch.testing.assert_close(closeness(lines, vps, 89.0).amax(1), closeness_of(cos.amin(1), 89.0))
    x = torch.tensor([0.001, 0.01, 0.02], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda c: closeness_of(c, 89.0), (x,))


def test_closeness_of_the_squared_sine():
    # 1 on the VP, 3/4 at the kernel's width, 0 from twice its sine on (sines squared)
    s5 = math.sin(math.radians(5.0)) ** 2
    sin2 = torch.tensor([0.0, s5, 4 * s5, 0.5, 1.0], dtype=torch.float64)
    torch.testing.assert_close(closeness_of(sin2, 5.0, "squared_sine"),
                               torch.tensor([1.0, 0.75, 0.0, 0.0, 0.0], dtype=torch.float64), atol=1e-12, rtol=0)
    # wider than 30 degrees the kernel reaches beyond a squared sine of 1: the sine is clamped there first
    assert closeness_of(torch.tensor([2.0]), 40.0, "squared_sine").item() == closeness_of(
        torch.tensor([1.0]), 40.0, "squared_sine").item() > 0
    x = torch.tensor([0.001, 0.004, 0.006], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda v: closeness_of(v, 5.0, "squared_sine"), (x,))


@pytest.mark.parametrize("measure", ["squared_sine", "squared_cosine"])
def test_closeness_of_in_place_is_the_same(measure):
    value = torch.rand(3, 50, generator=torch.Generator().manual_seed(0)) * 0.02
    kept = closeness_of(value, 5.0, measure, floor=-80.0)
    assert torch.equal(closeness_of(value.clone(), 5.0, measure, floor=-80.0, inplace=True), kept)
    # the squared cosine's kernel is the cosine's, to rounding
    if measure == "squared_cosine":
        torch.testing.assert_close(kept, closeness_of(value.sqrt(), 5.0, floor=-80.0))


def test_closeness_of_bad_measure_raises():
    with pytest.raises(ValueError, match="unknown closeness measure 'sine'"):
        closeness_of(torch.zeros(2), 5.0, "sine")
    with pytest.raises(ValueError, match="needs its width"):
        closeness_of(torch.zeros(2), None, "squared_sine")


def test_sharp_closeness_vs_closeness_ordering():
    # lines through points at increasing distance from the VP: both kernels rank them the same way, the sharp one
    # drops much faster
    vp = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64)
    offsets = torch.tensor([0.0, 0.002, 0.005, 0.02, 0.05, 0.2], dtype=torch.float64)
    lines = torch.stack([torch.ones_like(offsets), torch.zeros_like(offsets), -offsets], -1)  # x = offset
    lines = normalize(lines)[None]
    c = closeness(lines, vp)[0, 0]
    s = closeness(lines, vp, 89.0)[0, 0]
    assert (c[1:] < c[:-1]).all() and (s[1:] < s[:-1]).all()
    assert torch.equal(torch.argsort(c), torch.argsort(s))
    assert c[4] > 0.9 and s[4] < 0.05  # about 3 degrees off: still "close" for Eq. 14, not for the sharp kernel
    assert s[1] > 0.9


def test_line_vp_cosine_exception():
    with pytest.raises(ShapeError):
        line_vp_cosine(torch.zeros(2, 3), torch.zeros(2, 3))
    with pytest.raises(ShapeError):
        closeness(torch.zeros(1, 2, 3), torch.zeros(1, 4))


def test_closeness_gradcheck():
    lines = _randn(2, 5, 3, seed=4).requires_grad_()
    vps = _randn(2, 3, 3, seed=5).requires_grad_()
    assert gradcheck(line_vp_cosine, (lines, vps))
    assert gradcheck(closeness, (lines, vps))
    # the sharp kernel is steep: use lines close to passing through the VPs
    v = normalize(_randn(2, 3, 3, seed=6))
    near = torch.linalg.cross(v[:, :, None].expand(2, 3, 4, 3), _randn(2, 3, 4, 3, seed=7)).reshape(2, 12, 3)
    near = (near + 1e-3 * _randn(2, 12, 3, seed=8)).requires_grad_()
    assert gradcheck(lambda lines, vps: closeness(lines, vps, 89.0), (near, v.clone().requires_grad_()))


# ---------------------------------------------------------------------------------------------------------------
# segment_vp_angle


def test_segment_vp_angle_known():
    seg = torch.tensor([[[[0.0, 0.0], [0.0, 1.0]]]])
    out = segment_vp_angle(seg, torch.tensor([[[0.0, 1.0, 0.0], [1.0, 1.5, 1.0], [10.0, 0.5, 1.0], [0.0, -7.0, 1.0]]]))
    torch.testing.assert_close(out, torch.tensor([[[0.0], [45.0], [90.0], [0.0]]]))


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_segment_vp_angle_cardinality(b, n, dtype):
    g = torch.Generator().manual_seed(n)
    seg = (torch.rand(b, n, 2, 2, generator=g) * 100).to(dtype)
    vps = _randn(b, 3, 3, dtype=dtype)
    out = segment_vp_angle(seg, vps)
    assert out.shape == (b, 3, n) and out.dtype == dtype
    assert ((out >= 0) & (out <= 90 + 1e-4)).all()
    # invariant to the homogeneous scale/sign of the VP and to the segment's direction
    tol = dict(atol=1e-3, rtol=1e-3) if dtype == torch.float32 else {}
    torch.testing.assert_close(segment_vp_angle(seg.flip(-2), -3 * vps), out, **tol)
    assert segment_vp_angle(seg, vps[:, 0]).shape == (b, n)


def test_segment_vp_angle_lines_through_vp_and_degenerate():
    vp = (300.0, -200.0)
    seg = _lines_through(vp, [20.0, 95.0, 160.0])
    out = segment_vp_angle(seg, torch.tensor([[2 * vp[0], 2 * vp[1], 2.0]], dtype=torch.float64))
    assert out.abs().max() < 1e-6
    # zero-length segment, VP at the midpoint, zero VP: 0 and finite
    seg = torch.tensor([[[[1.0, 1.0], [1.0, 1.0]], [[0.0, 0.0], [2.0, 0.0]]]])
    out = segment_vp_angle(seg, torch.tensor([[[1.0, 0.0, 1.0], [0.0, 0.0, 0.0]]]))
    assert torch.isfinite(out).all()
    assert out.tolist() == [[[0.0, 0.0], [0.0, 0.0]]]


def test_segment_vp_angle_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        segment_vp_angle(torch.zeros(2, 2, 2), torch.zeros(2, 3))
    with pytest.raises(ShapeError):
        segment_vp_angle(torch.zeros(1, 2, 2, 2), torch.zeros(1, 2))
    g = torch.Generator().manual_seed(0)
    seg = (torch.rand(2, 3, 2, 2, generator=g, dtype=torch.float64) * 10).requires_grad_()
    vps = torch.tensor(
        [[[20.0, 5.0, 1.0], [3.0, -30.0, 1.0]], [[1.0, 0.3, 0.0], [-4.0, 8.0, 0.5]]], dtype=torch.float64
    )
    assert gradcheck(segment_vp_angle, (seg, vps.requires_grad_()))


# ---------------------------------------------------------------------------------------------------------------
# manhattan_score (line level)


def test_manhattan_score_known():
    c = torch.tensor([[[[1.0, 0.0], [0.0, 0.0], [0.0, 0.5]]]])
    torch.testing.assert_close(
        manhattan_score(c, torch.tensor([[1.0, 3.0]]), torch.tensor([[True, True]])), torch.tensor([[0.625]])
    )
    # a masked line does not count
    torch.testing.assert_close(
        manhattan_score(c, torch.tensor([[1.0, 3.0]]), torch.tensor([[True, False]])), torch.tensor([[1.0]])
    )


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", COUNTS)
def test_manhattan_score_cardinality(b, n, dtype):
    g = torch.Generator().manual_seed(b * n)
    c = torch.rand(b, 7, 3, n, generator=g).to(dtype)
    lengths = (torch.rand(b, n, generator=g) * 50).to(dtype)
    mask = torch.rand(b, n, generator=g) < 0.8
    mask[:, 0] = True
    out = manhattan_score(c, lengths, mask)
    assert out.shape == (b, 7) and out.dtype == dtype
    assert ((out >= 0) & (out <= 1)).all()
    w = lengths * mask
    expected = (c.amax(2) * w[:, None]).sum(-1) / w.sum(-1, keepdim=True)
    torch.testing.assert_close(out, expected)


def test_manhattan_score_true_frame_beats_wrong_frame():
    # segments of a box seen by a known camera, in the pseudo camera (where the scores are used): the true frame
    # scores higher than a slightly rotated one
    h, w = 480, 640
    K, R = camera_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (10.0, 5.0, 30.0, 500.0)), h, w)
    base = torch.tensor([[-2.0, -1.0, 8.0], [1.5, 0.5, 9.0], [0.0, 2.0, 12.0], [2.0, -2.0, 10.0]], dtype=torch.float64)
    segs = []
    for axis in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[axis] = 1.0
        segs.append(torch.stack([base, base + e], -2))
    X = torch.cat(segs)[None]
    x = torch.einsum("bij,bnkj->bnki", K @ R, X)
    seg = to_pseudo_camera(x[..., :2] / x[..., 2:], h, w)
    lines = segments_to_lines(seg)
    Kp = intrinsics_matrix(torch.tensor([pseudo_focal(h, w)], dtype=torch.float64), image_center(h, w))
    wrong = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (18.0, -3.0, 45.0)))
    vps = torch.stack([torch.linalg.solve(Kp, K @ R), torch.linalg.solve(Kp, K @ wrong)], 1).transpose(-1, -2)
    lengths = segment_lengths(seg)
    mask = torch.ones(1, 12, dtype=torch.bool)
    score = manhattan_score(closeness(lines, vps, 89.0), lengths, mask)
    assert score.shape == (1, 2)
    assert score[0, 0] > 0.999 and score[0, 1] < 0.5
    score_lin = manhattan_score(closeness(lines, vps), lengths, mask)
    assert score_lin[0, 0] > 0.999 and score_lin[0, 0] > score_lin[0, 1]


def test_manhattan_score_any_number_of_vps():
    c = torch.tensor([[[[0.2, 0.9], [0.7, 0.1]]]])  # (1, 1, 2 VPs, 2 lines)
    out = manhattan_score(c, torch.tensor([[1.0, 1.0]]), torch.tensor([[True, True]]))
    torch.testing.assert_close(out, torch.tensor([[0.8]]))


def test_manhattan_score_no_lines_and_zero_lengths():
    c = torch.rand(2, 3, 3, 4)
    out = manhattan_score(c, torch.rand(2, 4), torch.zeros(2, 4, dtype=torch.bool))
    assert torch.equal(out, torch.zeros(2, 3))
    out = manhattan_score(c, torch.zeros(2, 4), torch.ones(2, 4, dtype=torch.bool))
    assert torch.equal(out, torch.zeros(2, 3))
    out = manhattan_score(torch.rand(1, 2, 3, 0), torch.zeros(1, 0), torch.zeros(1, 0, dtype=torch.bool))
    assert out.shape == (1, 2) and torch.equal(out, torch.zeros(1, 2))


def test_manhattan_score_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        manhattan_score(torch.rand(2, 3, 4), torch.rand(1, 4), torch.ones(1, 4, dtype=torch.bool))
    with pytest.raises(ShapeError):
        manhattan_score(torch.rand(1, 2, 3, 4), torch.rand(4), torch.ones(1, 4, dtype=torch.bool))
    g = torch.Generator().manual_seed(0)
    c = torch.rand(2, 3, 3, 5, generator=g, dtype=torch.float64).requires_grad_()  # distinct values: no argmax ties
    lengths = (torch.rand(2, 5, generator=g, dtype=torch.float64) + 0.5).requires_grad_()
    mask = torch.tensor([[True, True, True, False, True], [True] * 5])
    assert gradcheck(lambda a, b: manhattan_score(a, b, mask), (c, lengths))


# ---------------------------------------------------------------------------------------------------------------
# topk_weighted_average (Eq. 23)


def test_topk_weighted_average_known():
    mean, w = topk_weighted_average(torch.tensor([[0.1, 0.6, 0.3]]), torch.tensor([[10.0, 20.0, 40.0]]), k=2)
    torch.testing.assert_close(mean, torch.tensor([(0.6 * 20 + 0.3 * 40) / 0.9]))
    torch.testing.assert_close(w, torch.tensor([[0.0, 2 / 3, 1 / 3]]))
    # k = 1 takes the best; k larger than F takes all
    mean, _ = topk_weighted_average(torch.tensor([[0.1, 0.6, 0.3]]), torch.tensor([[10.0, 20.0, 40.0]]), k=1)
    torch.testing.assert_close(mean, torch.tensor([20.0]))
    mean, w = topk_weighted_average(torch.tensor([[0.1, 0.6, 0.3]]), torch.tensor([[10.0, 20.0, 40.0]]), k=10)
    torch.testing.assert_close(mean, torch.tensor([(1 + 12 + 12) / 1.0]))
    torch.testing.assert_close(w.sum(1), torch.ones(1))


def test_topk_weighted_average_mask():
    scores = torch.tensor([[0.9, 0.6, 0.3, 0.2]])
    values = torch.tensor([[100.0, 20.0, 40.0, 80.0]])
    mask = torch.tensor([[False, True, True, True]])
    mean, w = topk_weighted_average(scores, values, k=2, mask=mask)
    torch.testing.assert_close(mean, torch.tensor([(0.6 * 20 + 0.3 * 40) / 0.9]))
    assert w[0, 0] == 0 and w[0, 3] == 0
    # fewer valid candidates than k
    mean, w = topk_weighted_average(scores, values, k=3, mask=torch.tensor([[False, False, True, False]]))
    torch.testing.assert_close(mean, torch.tensor([40.0]))
    torch.testing.assert_close(w, torch.tensor([[0.0, 0.0, 1.0, 0.0]]))


def test_topk_weighted_average_all_zero_scores_and_no_valid_candidate():
    values = torch.tensor([[1.0, 2.0, 3.0, 6.0], [1.0, 2.0, 3.0, 6.0]])
    scores = torch.zeros(2, 4)
    mask = torch.tensor([[True, True, True, True], [False, True, False, True]])
    mean, w = topk_weighted_average(scores, values, k=4, mask=mask)
    # all kept scores zero: the kept candidates count equally
    torch.testing.assert_close(mean, torch.tensor([3.0, 4.0]))
    torch.testing.assert_close(w, torch.tensor([[0.25] * 4, [0.0, 0.5, 0.0, 0.5]]))
    # no valid candidate: zero mean, zero weights, finite
    mean, w = topk_weighted_average(torch.rand(2, 4), values, k=2, mask=torch.zeros(2, 4, dtype=torch.bool))
    assert torch.equal(mean, torch.zeros(2)) and torch.equal(w, torch.zeros(2, 4))


def test_topk_weighted_average_of_scores_far_below_eps_sums_to_one():
    # a gravity prior far from every frame leaves scores near 1e-42 (subnormal in float32): the weights must still
    # sum to 1 (they once summed to 1e-35, which averaged every zenith to a zero vector)
    scores = torch.tensor([[1e-42, 3e-42, 0.0, 2e-40]])
    values = torch.tensor([[1.0, 2.0, 3.0, 6.0]])
    mean, w = topk_weighted_average(scores, values, k=2)
    torch.testing.assert_close(w.sum(1), torch.ones(1))
    assert w[0, 3] > 0.98 and w[0, 1] > 0 and w[0, 0] == 0
    assert 5.9 < float(mean[0]) <= 6.0


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("k", [1, 3, 8])
def test_topk_weighted_average_cardinality(b, k, dtype):
    g = torch.Generator().manual_seed(k)
    f = 10
    scores = torch.rand(b, f, generator=g).to(dtype)
    values = torch.randn(b, f, 3, 3, generator=g).to(dtype)
    mean, w = topk_weighted_average(scores, values, k=k)
    assert mean.shape == (b, 3, 3) and mean.dtype == dtype and w.shape == (b, f) and w.dtype == dtype
    torch.testing.assert_close(w.sum(1), torch.ones(b, dtype=dtype))
    assert ((w > 0).sum(1) == k).all()
    # the kept ones are the k best
    kept = w > 0
    top = scores.topk(k, dim=1).indices
    assert torch.equal(kept, torch.zeros_like(kept).scatter(1, top, True))
    torch.testing.assert_close(mean, (w[..., None, None] * values).sum(1))


def test_topk_weighted_average_gradcheck():
    g = torch.Generator().manual_seed(0)
    scores = (torch.rand(2, 6, generator=g, dtype=torch.float64) + 0.1).requires_grad_()  # distinct: no topk ties
    values = torch.randn(2, 6, 3, generator=g, dtype=torch.float64).requires_grad_()
    assert gradcheck(lambda s, v: topk_weighted_average(s, v, k=3)[0], (scores, values))
    with pytest.raises(ShapeError):
        topk_weighted_average(torch.rand(6), torch.rand(6))


def test_frame_manhattan_scores_of_valid_frames_only():
    from ngp_kornia.geometry import frame_manhattan_scores

    g = torch.Generator().manual_seed(0)
    lines = torch.randn(2, 40, 3, generator=g)
    vps = torch.randn(2, 30, 3, 3, generator=g)
    lengths = torch.rand(2, 40, generator=g)
    mask = torch.rand(2, 40, generator=g) > 0.2
    valid = torch.rand(2, 30, generator=g) > 0.5
    valid[1] = False  # an image without a valid frame
    full = frame_manhattan_scores(lines, vps, lengths, mask)
    part = frame_manhattan_scores(lines, vps, lengths, mask, valid=valid)
    assert part.shape == (2, 30) and bool((part[~valid] == 0).all())
    torch.testing.assert_close(part[valid], full[valid])
    everything = torch.ones(2, 30, dtype=torch.bool)
    assert torch.equal(frame_manhattan_scores(lines, vps, lengths, mask, valid=everything), full)
    assert torch.equal(frame_manhattan_scores(lines, vps, lengths, mask, valid=~everything), torch.zeros(2, 30))


@pytest.mark.parametrize("frames", [5, 256, 700])
@pytest.mark.parametrize("lines", [8, 40])
def test_frame_manhattan_scores_equal_the_single_product(frames, lines):
    """One product per VP (many frames and lines) and one over all VPs give the same scores."""
    from ngp_kornia.geometry.vp import frame_manhattan_scores

    g = torch.Generator().manual_seed(frames + lines)
    ln = normalize(torch.randn(1, lines, 3, generator=g))
    vps = normalize(torch.randn(1, frames, 3, 3, generator=g))
    lengths = torch.rand(1, lines, generator=g)
    mask = torch.ones(1, lines, dtype=torch.bool)
    scale = -1.0 / (2.0 * math.cos(math.radians(89.0)) ** 2)
    unit_vps, unit_lines = normalize(vps).reshape(1, frames * 3, 3), normalize(ln).transpose(-1, -2)
    nearest = (unit_vps @ unit_lines).square().reshape(1, frames, 3, lines).amin(2)
    kernel = (nearest * scale).clamp_min(-80.0).exp()
    expected = (kernel @ lengths[..., None])[..., 0] / lengths.sum(-1, keepdim=True)
    # one product per VP and one over all VPs sum in different orders on different CPUs: float32 rounding
    torch.testing.assert_close(frame_manhattan_scores(ln, vps, lengths, mask), expected, rtol=1e-5, atol=1e-7)


def test_true_positions_matches_stable_argsort():
    from ngp_kornia.geometry.vp import true_positions

    g = torch.Generator().manual_seed(0)
    for b in (1, 2, 3):
        mask = torch.rand(b, 50, generator=g) < 0.3
        count = int(mask.sum(-1).max())
        expected = mask.to(torch.uint8).argsort(dim=-1, descending=True, stable=True)[:, :count]
        assert torch.equal(true_positions(mask, count), expected)
