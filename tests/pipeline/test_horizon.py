"""The horizon refinement on exact synthetic Atlanta worlds: it must find the true horizon, keep the camera
consistent and leave degenerate inputs alone."""

import math

import pytest
import torch

from ngp_kornia.geometry import (
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    pitch_roll_from_up,
    rotation_from_angles,
    zenith_from_up,
)
from ngp_kornia.metrics import horizon_error
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.answer import calibration_from_camera
from ngp_kornia.pipeline.constants import cached
from ngp_kornia.pipeline.horizon import choose_horizon, refine_horizon, search_horizon
from ngp_kornia.pipeline.horizon_support import horizon_support, refine_up, up_from_pitch_roll
from ngp_kornia.pipeline.line_kernel import camera_segments, closeness_kernel, squared_sines
from ngp_kornia.pipeline.settings import HorizonSettings
from ngp_kornia.pipeline.trust_features import support_rival

FOCAL_SCALES = HorizonSettings().focal_scales

H, W = 480, 640


def camera(pitch, roll, yaw=0.0, fov_v=55.0):
    f = torch.tensor([H / 2 / math.tan(math.radians(fov_v / 2))], dtype=torch.float64)
    K = intrinsics_matrix(f, image_center(H, W).double())
    R = rotation_from_angles(*(torch.tensor([a], dtype=torch.float64) for a in (pitch, roll, yaw)))
    return K, R


def atlanta_segments(K, R, yaws=(0.0, 35.0, -50.0), n=30, clutter=0, seed=0):
    """Segments of vertical lines and of horizontal lines of several building blocks (one yaw each), projected by
    (K, R) and kept when inside the image; ``clutter`` random segments are added. (1, N, 2, 2) float32, mask."""
    g = torch.Generator().manual_seed(seed)
    dirs = [torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)]
    for yaw in yaws:
        a = math.radians(yaw)
        dirs.append(torch.tensor([math.cos(a), 0.0, math.sin(a)], dtype=torch.float64))
    segs = []
    for d in dirs:
        start = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([16.0, 8.0, 16.0])
        start[:, 2] += 14.0
        for a, length in zip(start, 1.5 + 2.0 * torch.rand(n, generator=g, dtype=torch.float64), strict=True):
            pa, pb = K[0] @ R[0] @ a, K[0] @ R[0] @ (a + length * d)
            if pa[2] <= 0 or pb[2] <= 0:
                continue
            pa, pb = pa[:2] / pa[2], pb[:2] / pb[2]
            if all(0 <= p[0] < W and 0 <= p[1] < H for p in (pa, pb)) and (pa - pb).norm() > 15:
                segs.append(torch.stack([pa, pb]))
    for _ in range(clutter):
        p = torch.rand(2, generator=g, dtype=torch.float64) * torch.tensor([W - 60.0, H - 60.0]) + 30
        a = torch.rand(1, generator=g, dtype=torch.float64) * math.pi
        q = p + 25 * torch.cat([torch.cos(a), torch.sin(a)])
        segs.append(torch.stack([p, q]))
    seg = torch.stack(segs)[None].float()
    return seg, torch.ones(seg.shape[:2], dtype=torch.bool)


def calibration(K, R):
    valid = torch.ones(1, dtype=torch.bool)
    return calibration_from_camera(K.float(), R.float(), torch.ones(1), valid, H, W)


def test_convention_up_from_pitch_roll_inverts_pitch_roll_from_up():
    pitch, roll = torch.tensor([12.0, -30.0, 0.0]), torch.tensor([-4.0, 7.5, 0.0])
    p, r = pitch_roll_from_up(up_from_pitch_roll(pitch, roll))
    assert torch.allclose(p, pitch, atol=1e-4) and torch.allclose(r, roll, atol=1e-4)


@pytest.mark.parametrize(("pitch", "roll", "wrong"), [(8.0, -3.0, 3.0), (-12.0, 5.0, -4.0), (1.0, 0.0, 2.5)])
def test_moves_a_wrong_horizon_to_the_true_one(pitch, roll, wrong):
    K, R = camera(pitch, roll)
    seg, mask = atlanta_segments(K, R, clutter=20)
    truth = calibration(K, R).horizon.double()
    _, R_off = camera(pitch + wrong, roll, 0.0)
    start = calibration(K, R_off)
    out = refine_horizon(start, seg, mask)
    before = horizon_error(start.horizon.double(), truth, H, W)
    after = horizon_error(out.horizon.double(), truth, H, W)
    assert float(after) < 0.25 * float(before)
    assert float(after) < 0.01


def test_true_horizon_stays_at_least_as_close():
    K, R = camera(6.0, 2.0)
    seg, mask = atlanta_segments(K, R, clutter=20, seed=1)
    start = calibration(K, R)
    out = refine_horizon(start, seg, mask)
    assert float(horizon_error(out.horizon.double(), start.horizon.double(), H, W)) < 0.005


def test_support_is_highest_at_the_true_horizon():
    K, R = camera(5.0, -2.0)
    seg, mask = atlanta_segments(K, R, seed=2)
    pitches = torch.tensor([[5.0, 2.0, 8.0, 5.0]])
    rolls = torch.tensor([[-2.0, -2.0, -2.0, 1.0]])
    support, dirs, weight = horizon_support(up_from_pitch_roll(pitches, rolls), seg, mask, K.float())
    assert int(support.argmax()) == 0
    assert dirs.shape == (1, 4, 4, 3) and weight.shape == (1, 4, 4)
    # the horizontal VPs found along the true horizon are the three blocks' directions (up to sign)
    cam = torch.stack(
        [
            R[0].float() @ torch.tensor([math.cos(math.radians(a)), 0.0, math.sin(math.radians(a))])
            for a in (0.0, 35.0, -50.0)
        ]
    )
    cos = (dirs[0, 0] @ cam.T).abs()
    assert bool((cos.amax(0) > math.cos(math.radians(1.0))).all())


def test_the_reported_camera_is_consistent():
    K, R = camera(10.0, 4.0)
    seg, mask = atlanta_segments(K, R, clutter=10, seed=3)
    _, R_off = camera(13.0, 4.0)
    out = refine_horizon(calibration(K, R_off), seg, mask, HorizonSettings(focal_scales=(1.0,)))
    Rn = out.R[0].double()
    assert torch.allclose(Rn @ Rn.T, torch.eye(3, dtype=torch.float64), atol=1e-5)
    assert torch.allclose(out.up, -out.R[..., :, 1])
    line = horizon_from_zenith(out.K, out.zenith)
    assert torch.allclose(line, out.horizon, atol=1e-5)
    p, r = pitch_roll_from_up(out.up)
    assert torch.allclose(p, out.pitch) and torch.allclose(r, out.roll)
    vz = out.vps[0, 1] / out.vps[0, 1].norm()
    assert float((vz * out.zenith[0]).sum().abs()) == pytest.approx(1.0, abs=1e-5)
    assert torch.equal(out.K, calibration(K, R_off).K)  # focal and K are the frame's


def test_no_segments_and_invalid_frames_leave_the_calibration_unchanged():
    K, R = camera(4.0, 1.0)
    start = calibration(K, R)
    empty = refine_horizon(start, torch.zeros(1, 3, 2, 2), torch.zeros(1, 3, dtype=torch.bool))
    for name in ("R", "horizon", "zenith", "pitch", "roll", "vps"):
        assert torch.equal(getattr(empty, name), getattr(start, name)), name
    seg, mask = atlanta_segments(K, R)
    _, R_off = camera(7.0, 1.0)
    off = calibration(K, R_off)
    off.valid = torch.zeros(1, dtype=torch.bool)
    assert torch.equal(refine_horizon(off, seg, mask).horizon, off.horizon)


def test_batch_equals_single_images():
    cams = [camera(8.0, -3.0), camera(-5.0, 2.0)]
    data = [atlanta_segments(K, R, clutter=5, seed=i) for i, (K, R) in enumerate(cams)]
    starts = [calibration(K, camera(pitch + 2.0, 0.0)[1]) for (K, _), pitch in zip(cams, (8.0, -5.0), strict=True)]
    n = max(s.shape[1] for s, _ in data)
    seg = torch.zeros(2, n, 2, 2)
    mask = torch.zeros(2, n, dtype=torch.bool)
    for i, (s, m) in enumerate(data):
        seg[i, : s.shape[1]], mask[i, : s.shape[1]] = s[0], m[0]
    batch = calibration_from_camera(
        torch.cat([s.K for s in starts]),
        torch.cat([s.R for s in starts]),
        torch.ones(2),
        torch.ones(2, dtype=torch.bool),
        H,
        W,
    )
    out = refine_horizon(batch, seg, mask)
    for i, (s, m) in enumerate(data):
        single = refine_horizon(starts[i], s, m)
        assert torch.allclose(out.horizon[i], single.horizon[0], atol=1e-4)


def test_refine_up_recovers_the_zenith_and_ignores_too_few_lines():
    K, R = camera(15.0, 6.0)
    seg, mask = atlanta_segments(K, R, seed=4)
    true_up = -R[..., :, 1].float()
    start = up_from_pitch_roll(torch.tensor([16.0]), torch.tensor([5.0]))
    up, ok = refine_up(start, seg, mask, K.float())
    assert bool(ok[0])
    assert float((up * true_up).sum()) > math.cos(math.radians(0.05))
    none, ok = refine_up(start, seg, torch.zeros_like(mask), K.float())
    assert not bool(ok[0]) and torch.allclose(none, start)


def test_refine_up_of_a_degenerate_camera_is_not_refined_and_does_not_fail():
    # a zero up vector or a near-singular K (what a wrong gravity prior once left) made the fit's matrix NaN, on which
    # torch.linalg.eigh raised _LinAlgError from inside calibrate()
    K, R = camera(15.0, 6.0)
    seg, mask = atlanta_segments(K, R, seed=4)
    start = up_from_pitch_roll(torch.tensor([16.0]), torch.tensor([5.0]))
    up, ok = refine_up(torch.zeros(1, 3), seg, mask, K.float())
    assert not bool(ok[0]) and torch.equal(up, torch.zeros(1, 3))
    singular = K.float().clone()
    singular[:, 0, 0] = singular[:, 1, 1] = 3e-33  # what the zero-weighted average of frames gave
    up, ok = refine_up(start, seg, mask, singular)
    assert not bool(ok[0]) and torch.allclose(up, start)


def test_parser_switch_recovers_the_camera():
    K, R = camera(9.0, -4.0, 20.0)
    seg, mask = atlanta_segments(K, R, clutter=10, seed=5)
    out = NeuralGeometricParser(ParserConfig().replace(refine=True))(torch.zeros(1, 3, H, W), seg, mask)
    assert bool(out.valid[0])
    assert float(horizon_error(out.horizon.double(), calibration(K, R).horizon.double(), H, W)) < 0.01
    assert bool(torch.isfinite(out.R).all())


def test_focal_scales_fix_a_wrong_focal_length_and_stay_consistent():
    K, R = camera(12.0, -2.0)
    seg, mask = atlanta_segments(K, R, clutter=10, seed=6)
    truth = calibration(K, R)
    K_off = K.clone()
    K_off[:, 0, 0] *= 0.8
    K_off[:, 1, 1] *= 0.8
    start = calibration(K_off, camera(14.0, -2.0)[1])
    plain = refine_horizon(start, seg, mask, HorizonSettings(focal_scales=(1.0,)))
    scaled = refine_horizon(start, seg, mask)  # the default scales: 0.8, 0.9, 1.1, 1.25
    err_plain = float(horizon_error(plain.horizon.double(), truth.horizon.double(), H, W))
    err_scaled = float(horizon_error(scaled.horizon.double(), truth.horizon.double(), H, W))
    assert err_scaled < 0.005 and err_scaled <= err_plain
    assert float(scaled.focal) == pytest.approx(float(K[0, 0, 0]), rel=0.02)  # 0.8 f times 1.25
    assert torch.allclose(scaled.K[:, 0, 0], scaled.focal)
    assert torch.allclose(horizon_from_zenith(scaled.K, scaled.zenith), scaled.horizon, atol=1e-5)
    assert float(scaled.fov_v) == pytest.approx(float(truth.fov_v), abs=1.0)


def test_float64_inputs_give_a_finite_float64_result():
    K, R = camera(7.0, 3.0)
    seg, mask = atlanta_segments(K, R, clutter=5, seed=7)
    out = NeuralGeometricParser(ParserConfig().replace(refine=True))(
        torch.zeros(1, 3, H, W, dtype=torch.float64), seg.double(), mask
    )
    assert out.horizon.dtype == torch.float64 and out.K.dtype == torch.float64
    for name in ("K", "R", "horizon", "zenith", "vps", "pitch", "roll", "focal"):
        assert bool(torch.isfinite(getattr(out, name)).all()), name
    assert float(horizon_error(out.horizon, calibration(K, R).horizon.double(), H, W)) < 0.01


def test_search_horizon_reports_the_hypothesis_that_refine_horizon_takes():
    K, R = camera(8.0, -3.0)
    seg, mask = atlanta_segments(K, R, clutter=20, seed=8)
    start = calibration(K, camera(11.0, -3.0)[1])
    found = search_horizon(start, seg, mask)
    assert float(found.support[0]) > float(found.frame_support[0]) * 1.08  # the wrong pitch loses support
    assert found.peaks.shape == found.frame_peaks.shape == (1, 4)
    assert bool((found.peaks[:, :-1] >= found.peaks[:, 1:]).all()) and 0 < float(found.peaks.sum()) <= 1.0
    assert float(found.scale[0]) in (1.0, *FOCAL_SCALES)
    assert torch.allclose(found.K[:, 0, 0], start.K[:, 0, 0] * found.scale)
    assert torch.allclose(found.up.norm(dim=-1), torch.ones(1))
    assert torch.allclose(found.up_refined.norm(dim=-1), torch.ones(1))
    out = refine_horizon(start, seg, mask)
    zenith = zenith_from_up(found.K, found.up)
    line = horizon_from_zenith(found.K, zenith / zenith.norm(dim=-1, keepdim=True))
    assert float(horizon_error(out.horizon.double(), line.double(), H, W)) < 1e-4
    # with a margin the hypothesis cannot beat, the frame's horizon is kept
    kept = refine_horizon(start, seg, mask, HorizonSettings(margin=10.0))
    assert torch.equal(kept.horizon, start.horizon) and torch.equal(kept.K, start.K)


def test_search_horizon_frame_support_is_the_support_of_the_frames_horizon():
    K, R = camera(4.0, 2.0)
    seg, mask = atlanta_segments(K, R, clutter=10, seed=9)
    start = calibration(K, camera(6.0, 2.0)[1])
    found = search_horizon(start, seg, mask)
    support, _, weight = horizon_support(start.up[:, None], seg, mask, start.K)
    assert torch.allclose(found.frame_support, support[:, 0], atol=1e-5)
    total = (seg[..., 1, :] - seg[..., 0, :]).norm(dim=-1).sum()
    assert torch.allclose(found.frame_peaks, weight[:, 0] / total, atol=1e-5)


def test_support_with_autograd_matches_the_in_place_path_and_has_gradients():
    K, R = camera(6.0, -1.0)
    seg, mask = atlanta_segments(K, R, clutter=15, seed=10)
    mask[:, -3:] = False  # padding
    ups = up_from_pitch_roll(torch.tensor([[6.0, 4.0, 8.0]]), torch.tensor([[-1.0, -1.0, 0.5]]))
    with torch.no_grad():
        plain = horizon_support(ups, seg, mask, K.float())
    seg_g, ups_g = seg.clone().requires_grad_(), ups.clone().requires_grad_()
    tracked = horizon_support(ups_g, seg_g, mask, K.float())
    for a, b in zip(plain, tracked, strict=True):
        assert torch.allclose(a, b.detach(), atol=1e-6)
    (tracked[0].sum() + tracked[1].sum()).backward()
    for g in (seg_g.grad, ups_g.grad):
        assert g is not None and bool(torch.isfinite(g).all()) and float(g.abs().sum()) > 0


def test_kernel_is_the_largest_closeness_over_kept_vps_even_on_a_midpoint():

    K, R = camera(3.0, 1.0)
    seg, mask = atlanta_segments(K, R, n=10, seed=11)
    K = K.float()
    cam = camera_segments(seg, K)
    g = torch.Generator().manual_seed(0)
    vps = torch.randn(1, 3, 4, 3, generator=g)
    vps[0, 0, 1] = torch.cat([cam.mid[0, 0], torch.ones(1)])  # a VP on a midpoint (up to rounding)
    vps[0, 1, 0] = 0.0  # a degenerate VP: |d| = 0 for every segment
    keep = torch.tensor([[[True, True, True, True], [True, True, False, False], [False, False, False, False]]])
    mask[:, :2] = False
    c = 4.0 * math.sin(math.radians(1.5)) ** 2
    expected = ((1.0 - squared_sines(cam, vps) / c).clamp_min(0.0) * keep[..., None] * mask[:, None, None]).amax(2)
    for grad in (False, True):
        with torch.set_grad_enabled(grad):
            v = vps.clone().requires_grad_(grad)
            # the fused kernel and the plain formula round differently (float32): a few ulps of values in [0, 1]
            torch.testing.assert_close(
                closeness_kernel(cam, v, 1.5, mask, keep).detach(), expected, rtol=0.0, atol=1e-6
            )


def test_choose_horizon_of_the_search_is_refine_horizon_and_the_hypotheses_are_reported():
    K, R = camera(8.0, -3.0)
    seg, mask = atlanta_segments(K, R, clutter=20, seed=8)
    start = calibration(K, camera(11.0, -3.0)[1])
    found = search_horizon(start, seg, mask)
    chosen, refined = choose_horizon(start, found), refine_horizon(start, seg, mask)
    for name in ("K", "R", "horizon", "pitch", "roll", "focal", "vps"):
        assert torch.equal(getattr(chosen, name), getattr(refined, name)), name
    hypotheses = 5 * 18  # five focal scales, each with the frame's own hypothesis and 17 pitches at the refined roll
    assert found.hypothesis_support.shape == (1, hypotheses) and found.hypothesis_horizon.shape == (1, hypotheses, 3)
    # column 0 is the frame's own horizon with its support; the best column is the best coarse support
    assert float(horizon_error(found.hypothesis_horizon[:, 0].double(), start.horizon.double(), H, W)) < 1e-5
    # the same support computed in a batch of hypotheses and alone: sums in another order (float32)
    torch.testing.assert_close(found.hypothesis_support[:, 0], found.frame_support, rtol=1e-5, atol=1e-6)
    assert float(found.hypothesis_support.max()) <= float(found.support) + 1e-6


def test_support_rival_is_high_only_where_the_lines_support_a_different_horizon():
    K, R = camera(8.0, -3.0)
    seg, mask = atlanta_segments(K, R, clutter=10, seed=3)
    other, other_mask = atlanta_segments(*camera(-2.0, -3.0), yaws=(20.0, -40.0), clutter=0, seed=4)
    truth = calibration(K, R)
    alone = support_rival(search_horizon(truth, seg, mask), truth.horizon, H, W)
    both = torch.cat([seg, other], 1), torch.cat([mask, other_mask], 1)
    mixed = support_rival(search_horizon(truth, *both), truth.horizon, H, W)
    # the verticals support every nearby horizon alike, so even a clean scene's rival keeps most of the support
    assert 0.0 <= float(alone) < 0.9 and 0.95 < float(mixed) <= 1.0


def test_up_vectors_do_not_depend_on_the_batch_they_are_computed_in():
    # the fine search returns the up vector it computed among the hypotheses, not one computed alone
    g = torch.Generator().manual_seed(3)
    pitch, roll = torch.rand(2, 4096, generator=g) * 180.0 - 90.0
    ups = up_from_pitch_roll(pitch, roll)
    for n in (1, 6, 17, 35):
        parts = [up_from_pitch_roll(p, r) for p, r in zip(pitch.split(n), roll.split(n), strict=True)]
        assert torch.equal(torch.cat(parts), ups)


def test_the_search_without_autograd_answers_ordinary_tensors():
    K, R = camera(6.0, -1.0)
    seg, mask = atlanta_segments(K, R, clutter=15, seed=10)
    with torch.no_grad():
        found = search_horizon(calibration(K, R), seg, mask)
    assert not any(t.is_inference() for t in found)
    found.up.add_(0.0)  # an ordinary tensor: in-place updates allowed
    ups = up_from_pitch_roll(torch.tensor([[6.0, 4.0]]), torch.tensor([[-1.0, 0.5]])).requires_grad_()
    support, dirs, _ = horizon_support(ups, seg.float().requires_grad_(), mask, K.float())
    (support.sum() + dirs.sum()).backward()
    assert ups.grad is not None and bool(torch.isfinite(ups.grad).all())
    assert torch.equal(search_horizon(calibration(K, R), seg, mask).support, found.support)  # with autograd


def test_constants_built_in_inference_mode_serve_callers_with_autograd():
    with torch.inference_mode():
        first = cached(("a constant of this test",), lambda: torch.ones(3))
    assert not first.is_inference() and cached(("a constant of this test",), lambda: torch.zeros(3)) is first
    (first * torch.ones(3, requires_grad=True)).sum().backward()  # usable with autograd
