"""Tests of ngp_kornia.pipeline.candidates: zenith candidates (Sec. 3.1, Eq. 3-4), the junction filter and
pseudo-horizon split
(Fig. 3), horizontal VP candidates and Manhattan-frame candidates (Sec. 3.2), all in the pseudo camera."""

import math

import pytest
import torch
from kornia.core.exceptions import ShapeError
from torch.autograd import gradcheck

from ngp_kornia.geometry import (
    cossim,
    dominant_eigenvector,
    intrinsics_matrix,
    is_near_vertical,
    pseudo_focal,
    segment_lengths,
    segments_to_lines,
    to_pseudo_camera,
    up_from_rotation,
    weighted_structure_tensor,
)
from ngp_kornia.geometry.frames import FrameCandidates, cat_frames, frames_from_vps
from ngp_kornia.pipeline.candidates import (
    horizontal_line_mask,
    sample_candidate_frames,
    sample_frames,
    sample_horizontal_pair_frames,
    sample_horizontal_vps,
    sample_pairs,
    sample_zenith_candidates,
    split_by_pseudo_horizon,
)
from tests.synthetic_camera import BATCHES, H, W, camera_from_angles

FP = pseudo_focal(H, W)


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


class _Camera:
    """A pixel camera (K with the principal point at the image centre, R from angles) and its pseudo-camera form."""

    def __init__(self, pitch, roll, yaw, focal, dtype=torch.float64):
        t = lambda v: torch.as_tensor(v, dtype=torch.float64).reshape(-1)  # noqa: E731
        self.focal = t(focal)
        self.K, self.R = camera_from_angles(t(pitch), t(roll), t(yaw), self.focal)
        self.b = self.R.shape[0]
        self.dtype = dtype
        f = self.focal / FP
        self.Kp = intrinsics_matrix(f, torch.zeros(2, dtype=torch.float64))  # K in the pseudo camera
        self.f_pseudo = f.to(dtype)
        self.vps = (self.Kp @ self.R).transpose(-1, -2).to(dtype)  # row i: VP of world axis i (pseudo camera)
        self.zenith = self.vps[:, 1]

    def segments(self, axis, n, length=1.5, seed=0, noise_px=0.0):
        """n segments along world axis ``axis`` with base points in front of the camera: pseudo units (B, n, 2, 2)."""
        g = _gen(seed)
        base_cam = torch.stack(
            [
                (torch.rand(self.b, n, generator=g) - 0.5) * 8,
                (torch.rand(self.b, n, generator=g) - 0.5) * 5,
                8 + 6 * torch.rand(self.b, n, generator=g),
            ],
            -1,
        ).double()
        base = torch.einsum("bji,bnj->bni", self.R, base_cam)  # world points: R^T x_cam
        e = torch.zeros(3, dtype=torch.float64)
        e[axis] = length
        X = torch.stack([base, base + e], -2)  # (B, n, 2, 3)
        return self.project(X, noise_px, seed + 1)

    def project(self, X, noise_px=0.0, seed=1):
        x = torch.einsum("bij,bnkj->bnki", self.K @ self.R, X)
        px = x[..., :2] / x[..., 2:]
        if noise_px:
            px = px + noise_px * torch.randn(px.shape, generator=_gen(seed), dtype=torch.float64)
        return to_pseudo_camera(px, H, W).to(self.dtype)


def _random_segments(b, n, seed, length=0.2, dtype=torch.float64):
    g = _gen(seed)
    p0 = (torch.rand(b, n, 2, generator=g) - 0.5) * 1.6
    a = torch.rand(b, n, generator=g) * math.pi
    d = torch.stack([torch.cos(a), torch.sin(a)], -1) * length
    return torch.stack([p0, p0 + d], -2).to(dtype)


def _up_angle_deg(Kp, zenith, true_up):
    """Angle in degrees between the up directions of homogeneous zeniths (B, M, 3) and true up vectors (B, 3)."""
    d = torch.linalg.solve(Kp[:, None].to(zenith), zenith.unsqueeze(-1)).squeeze(-1)
    return torch.rad2deg(torch.acos(cossim(d, true_up[:, None].to(d)).clamp(max=1.0)))


# ---------------------------------------------------------------------------------------------------------------
# sample_pairs


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n", [2, 5, 40])
def test_sample_pairs_cardinality_and_distinct(b, n):
    w = torch.rand(b, n, generator=_gen(n)) + 0.01
    i, j, ok = sample_pairs(w, 64, _gen(1))
    assert i.shape == j.shape == ok.shape == (b, 64)
    assert i.dtype == j.dtype == torch.long and ok.dtype == torch.bool
    assert ((i >= 0) & (i < n) & (j >= 0) & (j < n)).all()
    assert torch.equal(ok, i != j)  # every row usable: valid exactly when the two draws differ
    assert not (i[ok] == j[ok]).any()
    if n == 40:
        assert ok.float().mean() > 0.9


def test_sample_pairs_reproducible():
    w = torch.rand(3, 20, generator=_gen(0))
    a = sample_pairs(w, 50, _gen(123))
    b = sample_pairs(w, 50, _gen(123))
    c = sample_pairs(w, 50, _gen(124))
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)
    assert not torch.equal(a[0], c[0])


def test_sample_pairs_zero_weights_never_drawn_and_proportional():
    w = torch.tensor([[0.0, 1.0, 0.0, 3.0, 0.0]])
    i, j, ok = sample_pairs(w, 4000, _gen(0))
    drawn = torch.cat([i, j], 1)
    assert set(drawn.unique().tolist()) == {1, 3}
    frac = (drawn == 3).float().mean().item()
    assert frac == pytest.approx(0.75, abs=0.03)
    assert torch.equal(ok, i != j)


def test_sample_pairs_unusable_rows():
    # fewer than two drawable items: every pair invalid; other rows unaffected
    w = torch.tensor([[0.0, 0.0, 0.0], [0.0, 2.0, 0.0], [1.0, 1.0, 0.0]])
    i, j, ok = sample_pairs(w, 16, _gen(0))
    assert not ok[0].any() and not ok[1].any()
    assert ok[2].any() and ((i[2] < 2) & (j[2] < 2)).all()
    # no items at all
    i, j, ok = sample_pairs(torch.zeros(2, 0), 8, _gen(0))
    assert i.shape == (2, 8) and not ok.any()


def test_sample_pairs_exception():
    with pytest.raises(ShapeError):
        sample_pairs(torch.ones(5), 4)


# ---------------------------------------------------------------------------------------------------------------
# sample_zenith_candidates


def test_sample_zenith_candidates_synthetic_scene(dtype):
    cam = _Camera([12.0, -8.0], [6.0, -4.0], [25.0, -40.0], [450.0, 700.0], dtype=dtype)
    vertical = cam.segments(1, 24, length=2.0, seed=0, noise_px=0.1)
    horizontal = torch.cat([cam.segments(0, 15, seed=10), cam.segments(2, 15, seed=20)], 1)
    noise = _random_segments(2, 10, seed=3, dtype=dtype)
    seg = torch.cat([vertical, horizontal, noise], 1)
    mask = torch.ones(2, seg.shape[1], dtype=torch.bool)
    mask[1, -5:] = False  # padding
    lines, lengths = segments_to_lines(seg), segment_lengths(seg)
    Lz, lz_mask, Z, z_mask = sample_zenith_candidates(lines, lengths, mask, 64, 256, generator=_gen(0))
    assert Lz.shape == (2, 64, 3) and lz_mask.shape == (2, 64) and Z.shape == (2, 256, 3) and z_mask.shape == (2, 256)
    assert Lz.dtype == dtype and Z.dtype == dtype
    assert torch.isfinite(Z).all() and torch.isfinite(Lz).all()
    # L_z: near-vertical lines only (Eq. 4)
    assert lz_mask.all() and is_near_vertical(Lz)[lz_mask].all()
    # most candidates are near the true zenith
    assert z_mask.float().mean() > 0.8
    true_up = up_from_rotation(cam.R)
    err = _up_angle_deg(cam.Kp, Z, true_up)
    for k in range(2):
        e = err[k][z_mask[k]]
        assert e.median() < 1.5
        assert (e < 3.0).float().mean() > 0.6  # the rest pair a vertical line with a steep noise line
    # the structure-tensor mean (Eq. 10) of the inliers, as a zenith scorer would keep them, is on the zenith
    inlier = z_mask & (err < 5.0)
    mean = dominant_eigenvector(weighted_structure_tensor(Z, inlier.to(dtype)))
    assert (_up_angle_deg(cam.Kp, mean[:, None], true_up) < 0.5).all()


def test_sample_zenith_candidates_reproducible():
    cam = _Camera(10.0, 3.0, 20.0, 500.0)
    seg = torch.cat([cam.segments(1, 10), cam.segments(0, 10, seed=5)], 1)
    lines, lengths, mask = segments_to_lines(seg), segment_lengths(seg), torch.ones(1, 20, dtype=torch.bool)
    a = sample_zenith_candidates(lines, lengths, mask, 16, 32, generator=_gen(7))
    b = sample_zenith_candidates(lines, lengths, mask, 16, 32, generator=_gen(7))
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)


@pytest.mark.parametrize("b", BATCHES)
@pytest.mark.parametrize("n_vertical", [0, 2, 5])
def test_sample_zenith_candidates_valid_lines_are_vertical(b, n_vertical):
    cam = _Camera([10.0] * b, [5.0] * b, [30.0] * b, [500.0] * b)
    parts = [cam.segments(0, 6, seed=1), cam.segments(2, 6, seed=2)]
    if n_vertical:
        parts.append(cam.segments(1, n_vertical, seed=3))
    seg = torch.cat(parts, 1)
    lines, lengths = segments_to_lines(seg), segment_lengths(seg)
    mask = torch.ones(seg.shape[:2], dtype=torch.bool)
    Lz, lz_mask, Z, z_mask = sample_zenith_candidates(lines, lengths, mask, 8, 16, generator=_gen(0))
    assert Lz.shape == (b, 8, 3) and Z.shape == (b, 16, 3)
    assert is_near_vertical(Lz)[lz_mask].all()
    assert bool(lz_mask.any()) is (n_vertical >= 2)
    assert bool(z_mask.any()) is (n_vertical >= 2)


def test_sample_zenith_candidates_single_vertical_line():
    # documented: "Masks are all False for an image without two near-vertical lines"
    cam = _Camera(10.0, 5.0, 30.0, 500.0)
    seg = torch.cat([cam.segments(0, 6, seed=1), cam.segments(1, 1, seed=3)], 1)
    lines, lengths = segments_to_lines(seg), segment_lengths(seg)
    mask = torch.ones(1, 7, dtype=torch.bool)
    Lz, lz_mask, Z, z_mask = sample_zenith_candidates(lines, lengths, mask, 16, 16, generator=_gen(0))
    assert not z_mask.any()
    assert not lz_mask.any(), "L_z is marked valid but holds lines drawn from all lines (one vertical line only)"


def test_sample_zenith_candidates_no_lines_and_identical_lines():
    # an all-False mask (image with no lines): all invalid, finite
    lines = torch.randn(2, 5, 3, generator=_gen(0))
    mask = torch.zeros(2, 5, dtype=torch.bool)
    Lz, lz_mask, Z, z_mask = sample_zenith_candidates(lines, torch.ones(2, 5), mask, 8, 8, generator=_gen(0))
    assert not lz_mask.any() and not z_mask.any()
    assert torch.isfinite(Lz).all() and torch.isfinite(Z).all()
    # two copies of the same vertical segment: no intersection, no valid candidate
    seg = torch.tensor([[[[0.1, -0.4], [0.12, 0.4]], [[0.1, -0.4], [0.12, 0.4]]]])
    lines = segments_to_lines(seg)
    _, _, Z, z_mask = sample_zenith_candidates(lines, segment_lengths(seg), torch.ones(1, 2, dtype=torch.bool), 4, 16)
    assert not z_mask.any()


def test_sample_zenith_candidates_zero_lines():
    # a batch where no image has a line (detect_segments then gives N = 0): all invalid, finite, no crash
    # (sample_pairs supports N = 0 itself)
    Lz, lz_mask, Z, z_mask = sample_zenith_candidates(
        torch.zeros(1, 0, 3), torch.zeros(1, 0), torch.zeros(1, 0, dtype=torch.bool), 8, 8
    )
    assert Lz.shape == (1, 8, 3) and Z.shape == (1, 8, 3)
    assert not lz_mask.any() and not z_mask.any() and torch.isfinite(Z).all()


def test_sample_zenith_candidates_exception():
    with pytest.raises(ShapeError):
        sample_zenith_candidates(torch.zeros(4, 3), torch.zeros(4), torch.ones(4, dtype=torch.bool))


# ---------------------------------------------------------------------------------------------------------------
# horizontal_line_mask (junction filter) and split_by_pseudo_horizon


def _box_scene(cam):
    """Edges of a box in front of the camera plus floating horizontal segments away from its corners."""
    lo = torch.tensor([-1.5, -1.0, 8.0], dtype=torch.float64)
    hi = torch.tensor([1.5, 1.5, 11.0], dtype=torch.float64)
    corners = {}
    for ix in range(2):
        for iy in range(2):
            for iz in range(2):
                corners[ix, iy, iz] = torch.stack([(lo, hi)[ix][0], (lo, hi)[iy][1], (lo, hi)[iz][2]])
    # rotate the box about the vertical so both horizontal directions are visible, keep world axes aligned
    vertical, horizontal = [], []
    for ix in range(2):
        for iz in range(2):
            vertical.append(torch.stack([corners[ix, 0, iz], corners[ix, 1, iz]]))
    for iy in range(2):
        for iz in range(2):
            horizontal.append(torch.stack([corners[0, iy, iz], corners[1, iy, iz]]))
        for ix in range(2):
            horizontal.append(torch.stack([corners[ix, iy, 0], corners[ix, iy, 1]]))
    floating = [
        torch.tensor([[-4.0, 3.0, 14.0], [-2.5, 3.0, 14.0]], dtype=torch.float64),
        torch.tensor([[3.5, -2.5, 13.0], [3.5, -2.5, 15.0]], dtype=torch.float64),
    ]
    X = torch.stack(vertical + horizontal + floating)[None]  # (1, 4 + 8 + 2, 2, 3)
    return cam.project(X)


def test_horizontal_line_mask_junction_filter():
    cam = _Camera(8.0, 4.0, 0.0, 500.0)
    seg = _box_scene(cam)
    n = seg.shape[1]
    mask = torch.ones(1, n, dtype=torch.bool)
    out = horizontal_line_mask(seg, mask, cam.zenith, min_lines=1)
    assert out.shape == (1, n) and out.dtype == torch.bool
    expected = torch.tensor([[False] * 4 + [True] * 8 + [False] * 2])
    assert torch.equal(out, expected)
    # fall-back: too few junction lines -> every non-vertical line
    out = horizontal_line_mask(seg, mask, cam.zenith, min_lines=9)
    assert torch.equal(out, torch.tensor([[False] * 4 + [True] * 10]))
    # masked lines are never selected; without vertical lines there are no junctions (fall-back to all others)
    mask2 = mask.clone()
    mask2[0, 4] = False
    out = horizontal_line_mask(seg, mask2, cam.zenith, min_lines=1)
    assert not out[0, 4] and out[0, 5:12].all() and not out[0, 12:].any()
    no_vertical = mask.clone()
    no_vertical[0, :4] = False
    out = horizontal_line_mask(seg, no_vertical, cam.zenith, min_lines=1)
    assert torch.equal(out, no_vertical)


@pytest.mark.parametrize("b", BATCHES)
def test_horizontal_line_mask_cardinality_and_empty(b):
    seg = _random_segments(b, 7, seed=b)
    zenith = torch.tensor([0.0, -1.0, 0.1]).double().expand(b, 3)
    out = horizontal_line_mask(seg, torch.zeros(b, 7, dtype=torch.bool), zenith)
    assert out.shape == (b, 7) and not out.any()
    with pytest.raises(ShapeError):
        horizontal_line_mask(seg, torch.ones(b, 7, dtype=torch.bool), zenith[:, :2])


@pytest.mark.parametrize("yaw", [25.0, -35.0])
def test_split_by_pseudo_horizon_left_and_right_vps(yaw, dtype):
    # focal FP: the pseudo camera is the true camera, so the pseudo-horizon is the horizon and every line through a
    # horizontal VP crosses it at that VP
    cam = _Camera([6.0, -10.0], [4.0, -7.0], [yaw, yaw], [FP, FP], dtype=dtype)
    x_lines = segments_to_lines(cam.segments(0, 8, seed=1))
    z_lines = segments_to_lines(cam.segments(2, 8, seed=2))
    lines = torch.cat([x_lines, z_lines], 1)
    right = split_by_pseudo_horizon(lines, cam.zenith)
    assert right.shape == (2, 16) and right.dtype == torch.bool
    # which group holds which axis follows from where the VPs are: yaw > 0 puts world z left, world x right
    x_right = yaw > 0
    assert (right[:, :8] == x_right).all()
    assert (right[:, 8:] == (not x_right)).all()
    # invariant to the sign of the lines and of the zenith
    assert torch.equal(split_by_pseudo_horizon(-lines, -3 * cam.zenith), right)


def test_split_by_pseudo_horizon_parallel_lines_count_as_right():
    zenith = torch.tensor([[0.0, -1.0, 0.2]])  # horizon y = 0.2: 0 x + 1 y - 0.2 ... as a line (0, -1, 0.2)
    lines = torch.tensor([[[0.0, 1.0, -0.7], [1.0, 1.0, 0.5], [-1.0, 1.0, 0.5]]])
    out = split_by_pseudo_horizon(lines, zenith)
    # the horizontal line meets the horizon at infinity; x + y + 0.5 = 0 crosses y = 0.2 at x = -0.7 (left);
    # -x + y + 0.5 = 0 crosses it at x = 0.7 (right)
    assert out.tolist() == [[True, False, True]]


def test_split_by_pseudo_horizon_exception():
    with pytest.raises(ShapeError):
        split_by_pseudo_horizon(torch.zeros(2, 3), torch.zeros(2, 3))


# ---------------------------------------------------------------------------------------------------------------
# sample_horizontal_vps


def test_sample_horizontal_vps_synthetic_scene():
    cam = _Camera(8.0, 5.0, 30.0, FP)
    seg = torch.cat([cam.segments(0, 10, seed=1), cam.segments(2, 10, seed=2), cam.segments(1, 6, seed=3)], 1)
    lines, lengths = segments_to_lines(seg), segment_lengths(seg)
    horizontal = torch.tensor([[True] * 20 + [False] * 6])
    right = split_by_pseudo_horizon(lines, cam.zenith)
    vps, valid = sample_horizontal_vps(lines, lengths, horizontal, right, count=64, generator=_gen(0))
    assert vps.shape == (1, 64, 3) and valid.shape == (1, 64)
    assert valid.float().mean() > 0.8
    # right-hand group first (world x, yaw > 0), left-hand group second (world z)
    assert (cossim(vps[0, :32][valid[0, :32]], cam.vps[0, 0]) > 1 - 1e-9).all()
    assert (cossim(vps[0, 32:][valid[0, 32:]], cam.vps[0, 2]) > 1 - 1e-9).all()


def test_sample_horizontal_vps_no_lines():
    lines = torch.randn(2, 6, 3, generator=_gen(0))
    none = torch.zeros(2, 6, dtype=torch.bool)
    vps, valid = sample_horizontal_vps(lines, torch.ones(2, 6), none, none, count=10, generator=_gen(0))
    assert vps.shape == (2, 10, 3) and not valid.any() and torch.isfinite(vps).all()


# ---------------------------------------------------------------------------------------------------------------
# frames_from_vps and frame sampling


def _assert_frame_matches(fc, cam, f, k=0, tol=1e-6):
    """Frame k of every batch: focal, rotation up to the Manhattan ambiguity, VPs of its own rotation."""
    R, Rt = fc.R[:, k], cam.R.to(fc.R)
    torch.testing.assert_close(fc.focal[:, k], f, atol=tol, rtol=tol)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=R.dtype).expand_as(R), atol=tol, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(R.shape[0], dtype=R.dtype), atol=tol, rtol=0)
    torch.testing.assert_close(R[:, :, 1], Rt[:, :, 1], atol=tol, rtol=0)  # down, pointing down
    c0 = torch.maximum((R[:, :, 0] * Rt[:, :, 0]).sum(-1).abs(), (R[:, :, 0] * Rt[:, :, 2]).sum(-1).abs())
    torch.testing.assert_close(c0, torch.ones_like(c0), atol=tol, rtol=0)
    Kp = intrinsics_matrix(fc.focal[:, k], torch.zeros(2, dtype=R.dtype))
    for i in range(3):
        assert (cossim(fc.vps[:, k, i], (Kp @ R)[:, :, i]) > 1 - tol).all()
    torch.testing.assert_close(fc.zenith[:, k], fc.vps[:, k, 1])
    torch.testing.assert_close(fc.horizontal[:, k], fc.vps[:, k, 0])


@pytest.mark.parametrize("b", BATCHES)
def test_frames_from_vps_recovers_camera(b, dtype):
    g = _gen(b)
    pitch = (5 + 20 * torch.rand(b, generator=g)) * torch.where(torch.rand(b, generator=g) < 0.5, -1, 1)
    roll = (torch.rand(b, generator=g) - 0.5) * 30
    yaw = (torch.rand(b, generator=g) - 0.5) * 80
    focal = 300 + 600 * torch.rand(b, generator=g)
    cam = _Camera(pitch, roll, yaw, focal, dtype=dtype)
    v = cam.vps
    valid = torch.ones(b, 1, dtype=torch.bool)
    tol = 1e-3 if dtype == torch.float32 else 1e-8
    # the paper's (zenith, horizontal) pair, with arbitrary homogeneous scale and sign
    fc = frames_from_vps(-v[:, 1:2], 2 * v[:, 0:1], valid)
    assert isinstance(fc, FrameCandidates)
    assert fc.R.shape == (b, 1, 3, 3) and fc.vps.shape == (b, 1, 3, 3) and fc.focal.shape == (b, 1)
    assert fc.R.dtype == dtype and fc.focal.dtype == dtype
    assert fc.valid.all()
    _assert_frame_matches(fc, cam, cam.f_pseudo, tol=tol)


@pytest.mark.parametrize(("first", "second"), [(0, 1), (2, 1), (0, 2), (2, 0)])
def test_frames_from_vps_vertical_axis_relabelled(first, second):
    # the "zenith" input may be a horizontal VP (two steep lines meeting at a horizontal VP), or both inputs
    # horizontal VPs: the most image-vertical axis is still labelled as down
    cam = _Camera([10.0, -15.0], [5.0, 12.0], [30.0, -20.0], [500.0, 800.0])
    v = cam.vps
    fc = frames_from_vps(v[:, first : first + 1], v[:, second : second + 1], torch.ones(2, 1, dtype=torch.bool))
    assert fc.valid.all()
    _assert_frame_matches(fc, cam, cam.f_pseudo)


def test_frames_from_vps_level_camera_needs_two_horizontal_vps():
    # level camera: the zenith is at infinity, a (zenith, horizontal) pair cannot fix the focal length
    cam = _Camera(0.0, 0.0, 30.0, 500.0)
    v = cam.vps
    valid = torch.ones(1, 1, dtype=torch.bool)
    fc = frames_from_vps(v[:, 1:2], v[:, 0:1], valid)
    assert not fc.valid.any() and fc.focal[0, 0] == 0
    assert torch.isfinite(fc.R).all() and torch.isfinite(fc.vps).all()
    fc = frames_from_vps(v[:, 0:1], v[:, 2:3], valid)
    assert fc.valid.all()
    _assert_frame_matches(fc, cam, cam.f_pseudo)


def test_frames_from_vps_invalid_frames():
    cam = _Camera(10.0, 5.0, 30.0, 500.0)
    v = cam.vps
    z = v[:, 1:2].expand(1, 4, 3).clone()
    h = v[:, 0:1].expand(1, 4, 3).clone()
    h[0, 1] = 2 * z[0, 1]  # the same point twice: not orthogonal for any focal
    valid = torch.tensor([[True, True, False, True]])
    fc = frames_from_vps(z, h, valid, focal_range=(0.8, 4.0))
    assert fc.valid.tolist() == [[True, False, False, True]]
    assert fc.focal[0, 1] == 0 and fc.focal[0, 2] == 0
    # out of the focal range
    fc2 = frames_from_vps(z, h, valid, focal_range=(2.0, 4.0))  # true focal 500 / 320 = 1.56
    assert not fc2.valid.any() and (fc2.focal == 0).all()
    for fr in (fc, fc2):
        for t in (fr.R, fr.vps, fr.zenith, fr.horizontal, fr.focal):
            assert torch.isfinite(t).all()
    # zero (padding) VPs
    fc3 = frames_from_vps(torch.zeros(2, 3, 3), torch.zeros(2, 3, 3), torch.ones(2, 3, dtype=torch.bool))
    assert not fc3.valid.any() and torch.isfinite(fc3.R).all() and torch.isfinite(fc3.vps).all()


def test_frames_from_vps_exception_and_gradcheck():
    with pytest.raises(ShapeError):
        frames_from_vps(torch.zeros(2, 3), torch.zeros(2, 3), torch.ones(2, dtype=torch.bool))
    cam = _Camera([10.0, -12.0], [5.0, 3.0], [30.0, 10.0], [500.0, 700.0])
    a = cam.vps[:, 1:2].clone().requires_grad_()
    b = cam.vps[:, 0:1].clone().requires_grad_()
    valid = torch.ones(2, 1, dtype=torch.bool)

    def fn(x, y):
        fc = frames_from_vps(x, y, valid)
        return fc.focal, fc.R, fc.vps

    assert gradcheck(fn, (a, b))


def test_cat_frames():
    cam = _Camera([10.0, -12.0], [5.0, 3.0], [30.0, 10.0], [500.0, 700.0])
    v = cam.vps
    f1 = frames_from_vps(v[:, 1:2], v[:, 0:1], torch.ones(2, 1, dtype=torch.bool))
    f2 = frames_from_vps(v[:, 1:2].expand(2, 3, 3), v[:, 2:3].expand(2, 3, 3), torch.zeros(2, 3, dtype=torch.bool))
    out = cat_frames(f1, f2)
    assert out.R.shape == (2, 4, 3, 3) and out.focal.shape == (2, 4) and out.zenith.shape == (2, 4, 3)
    assert out.valid.tolist() == [[True, False, False, False]] * 2
    torch.testing.assert_close(out.R[:, :1], f1.R)
    torch.testing.assert_close(out.vps[:, 1:], f2.vps)


def test_sample_frames_recovers_camera():
    cam = _Camera([10.0, -15.0], [5.0, 8.0], [30.0, -25.0], [500.0, 800.0])
    junk = torch.randn(2, 6, 3, generator=_gen(0), dtype=torch.float64)
    zenith = torch.cat([cam.vps[:, 1:2].expand(2, 3, 3), junk], 1)
    zw = torch.tensor([[1.0, 0.5, 2.0] + [0.0] * 6] * 2, dtype=torch.float64)
    horizontal = torch.cat([cam.vps[:, 0:1], junk[:, :3], cam.vps[:, 2:3]], 1)
    hmask = torch.tensor([[True, False, False, False, True]] * 2)
    fc = sample_frames(zenith, zw, horizontal, hmask, count=32, generator=_gen(1))
    assert fc.R.shape == (2, 32, 3, 3) and fc.valid.shape == (2, 32)
    assert fc.valid.all()
    for k in range(32):
        _assert_frame_matches(fc, cam, cam.f_pseudo, k=k)
    again = sample_frames(zenith, zw, horizontal, hmask, count=32, generator=_gen(1))
    assert torch.equal(again.R, fc.R)


def test_sample_frames_no_valid_candidate():
    zenith = torch.randn(2, 4, 3, generator=_gen(0))
    horizontal = torch.randn(2, 5, 3, generator=_gen(1))
    # no zenith weight in row 0, no horizontal VP in row 1
    zw = torch.tensor([[0.0] * 4, [1.0] * 4])
    hmask = torch.tensor([[True] * 5, [False] * 5])
    fc = sample_frames(zenith, zw, horizontal, hmask, count=16, generator=_gen(2))
    assert fc.valid.shape == (2, 16) and not fc.valid.any()
    assert (fc.focal == 0).all()
    for t in (fc.R, fc.vps, fc.zenith, fc.horizontal):
        assert torch.isfinite(t).all()
    with pytest.raises(ShapeError):
        sample_frames(zenith, zw[0], horizontal, hmask, 8)


def test_sample_frames_zero_candidates():
    # no zenith and no horizontal candidate at all: all invalid, finite, no crash (_draw supports zero candidates)
    empty = torch.zeros(1, 0, 3)
    fc = sample_frames(empty, torch.zeros(1, 0), empty, torch.zeros(1, 0, dtype=torch.bool), 8)
    assert fc.valid.shape == (1, 8) and not fc.valid.any() and torch.isfinite(fc.R).all()


def test_sample_horizontal_pair_frames():
    cam = _Camera([0.0, 7.0], [0.0, -4.0], [30.0, 20.0], [500.0, 650.0])  # the first camera is level
    junk = torch.randn(2, 2, 3, generator=_gen(0), dtype=torch.float64)
    right = torch.cat([cam.vps[:, 0:1].expand(2, 2, 3), junk], 1)  # world x: right-hand group (yaw > 0)
    left = torch.cat([junk, cam.vps[:, 2:3].expand(2, 2, 3)], 1)
    horizontal = torch.cat([right, left], 1)
    hmask = torch.tensor([[True, True, False, False, False, False, True, True]] * 2)
    fc = sample_horizontal_pair_frames(horizontal, hmask, count=16, generator=_gen(3))
    assert fc.R.shape == (2, 16, 3, 3)
    assert fc.valid.all()
    for k in range(16):
        _assert_frame_matches(fc, cam, cam.f_pseudo, k=k)
    # an empty group: no valid frame
    fc = sample_horizontal_pair_frames(horizontal, hmask & torch.tensor([True] * 4 + [False] * 4), count=8)
    assert not fc.valid.any() and torch.isfinite(fc.R).all()


@pytest.mark.parametrize("pair_count", [0, 64])
@pytest.mark.parametrize("focal", [None, 1.5])
def test_sample_candidate_frames_equals_both_samplers(pair_count, focal):
    # the same draws in the same order and the same frames as the two samplers concatenated
    zenith = torch.randn(2, 32, 3, generator=_gen(0))
    zw = torch.rand(2, 32, generator=_gen(1)) * (torch.rand(2, 32, generator=_gen(2)) > 0.3)
    horizontal = torch.randn(2, 64, 3, generator=_gen(3))
    hmask = torch.rand(2, 64, generator=_gen(4)) > 0.2
    gens = [_gen(5), _gen(5)]
    out = sample_candidate_frames(zenith, zw, horizontal, hmask, 128, pair_count, generator=gens, focal=focal)
    gens = [_gen(5), _gen(5)]
    expected = sample_frames(zenith, zw, horizontal, hmask, 128, generator=gens, focal=focal)
    if pair_count:
        pairs = sample_horizontal_pair_frames(horizontal, hmask, pair_count, generator=gens, focal=focal)
        expected = cat_frames(expected, pairs)
    assert out.valid.shape == (2, 128 + pair_count) and out.valid.any()
    for name in FrameCandidates.__dataclass_fields__:
        assert torch.equal(getattr(out, name), getattr(expected, name)), name


# the fast paths of frame building and the junction filter give the values of the plain operations


@pytest.mark.parametrize("n", [3, 12, 40, 300])
@pytest.mark.parametrize("b", [1, 3])
def test_nearest_vertical_endpoint_equals_cdist_minimum(b, n):
    from ngp_kornia.pipeline.candidates import nearest_vertical_endpoint

    g = _gen(n + b)
    for dtype in (torch.float32, torch.float64):
        seg = torch.rand(b, n, 2, 2, generator=g, dtype=dtype) * 2 - 1
        vertical = torch.rand(b, n, generator=g) < 0.4
        vertical[0, 0] = True
        ends = seg.flatten(1, 2)
        dist = torch.cdist(ends, ends).masked_fill(~vertical.repeat_interleave(2, 1)[:, None], float("inf"))
        # for more than 25 points both sides use the expansion |x|^2 - 2 x.y + |y|^2, whose matrix product rounds
        # differently on different CPUs; its error in a squared distance is a few ulps of |x|^2 + |y|^2 <= 4, so in
        # a distance near zero up to about 4 sqrt(eps) (7e-9 seen in float64)
        torch.testing.assert_close(
            nearest_vertical_endpoint(seg, vertical), dist.amin(-1), rtol=0.0, atol=4 * torch.finfo(dtype).eps ** 0.5
        )
    assert torch.isinf(nearest_vertical_endpoint(seg, torch.zeros_like(vertical))).all()


def test_frames_from_vps_rows_and_layout_of_vps():
    """The VPs are the unit rows of (K R)^T, stored as the transpose of a contiguous K R (its columns)."""
    g = _gen(4)
    a = torch.randn(2, 300, 3, generator=g)
    b = torch.randn(2, 300, 3, generator=g)
    fr = frames_from_vps(a, b, torch.ones(2, 300, dtype=torch.bool), (0.1, 50.0))
    f = torch.where(fr.valid, fr.focal, 1.0)
    K = torch.diag_embed(torch.stack([f, f, torch.ones_like(f)], -1))
    expected = K @ fr.R
    expected = expected.transpose(-1, -2) / expected.transpose(-1, -2).norm(dim=-1, keepdim=True)
    # the same VPs computed another way (a product, then a normalisation): equal up to float32 rounding
    torch.testing.assert_close(fr.vps, expected, rtol=1e-6, atol=1e-6)
    assert fr.vps.transpose(-1, -2).is_contiguous()
