"""The principal point: the orthocentre of three VPs, its estimate from segments under a prior, and calibrate()'s
``principal_point`` argument (given or estimated)."""

import pytest
import torch

from ngp_kornia import NeuralGeometricParser, Priors, calibrate
from ngp_kornia.geometry import horizon_from_zenith, intrinsics_matrix, rotation_from_angles
from ngp_kornia.pipeline.camera_model import moved_calibration
from ngp_kornia.pipeline.principal_point import estimate_principal_point, orthocentre
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.render import RenderConfig, render_scene


def _camera(pp, pitch=12.0, roll=-6.0, yaw=35.0, focal=420.0):
    K = intrinsics_matrix(torch.tensor([focal], dtype=torch.float64), torch.tensor(pp, dtype=torch.float64))
    R = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (pitch, roll, yaw)))
    return K, R


def test_orthocentre_of_three_orthogonal_vps_is_the_principal_point():
    for pp in ([300.0, 250.0], [340.5, 221.0]):
        K, R = _camera(pp)
        h = orthocentre((K @ R).transpose(1, 2))
        assert torch.allclose(h[:, :2] / h[:, 2:], torch.tensor([pp], dtype=torch.float64), atol=1e-6)


def _segments_towards_vps(K, R, count=40, seed=0):
    """Segments 60 px long, each pointing exactly at one of the camera's three VPs, spread over a 640x480 image."""
    g = torch.Generator().manual_seed(seed)
    vps = (K @ R)[0].T  # rows
    segs = []
    for i in range(3 * count):
        v = vps[i % 3]
        start = torch.rand(2, generator=g, dtype=torch.float64) * torch.tensor([600.0, 440.0]) + 20
        towards = v[:2] - start * v[2]
        towards = towards / towards.norm() * torch.sign(v[2] if v[2] != 0 else torch.tensor(1.0))
        segs.append(torch.stack([start, start + 60 * towards]))
    return torch.stack(segs)[None], torch.ones(1, 3 * count, dtype=torch.bool)


def test_estimate_finds_an_off_centre_principal_point_and_the_prior_holds_it():
    truth = [335.0, 226.0]
    K_true, R = _camera(truth)
    segments, mask = _segments_towards_vps(K_true, R)
    K_centred, _ = _camera([319.5, 239.5])
    # a weak prior: exact lines pull the estimate onto the truth (the start is 20 px off)
    found = estimate_principal_point(K_centred, R, segments, mask, prior_std=1000.0)
    assert torch.allclose(found.point, torch.tensor([truth], dtype=torch.float64), atol=0.5)
    assert bool((found.std < 2.0).all())
    # a known centre (prior 0) is kept; no segments: the prior's mean and standard deviation
    assert torch.equal(estimate_principal_point(K_centred, R, segments, mask, 0.0).point, K_centred[:, :2, 2])
    none = estimate_principal_point(K_centred, R, segments, torch.zeros_like(mask), 12.0)
    assert torch.equal(none.point, K_centred[:, :2, 2]) and none.std.tolist() == [[12.0, 12.0]]


def test_moved_calibration_keeps_the_horizon_the_zeniths_polar():
    cal = calibrate(torch.rand(2, 3, 64, 80), weights="none")
    moved = moved_calibration(cal, torch.tensor([[5.0, -3.0], [0.0, 2.0]]))
    assert torch.allclose(moved.K[:, :2, 2], cal.K[:, :2, 2] + torch.tensor([[5.0, -3.0], [0.0, 2.0]]))
    assert torch.allclose(moved.horizon, horizon_from_zenith(moved.K, moved.zenith), atol=1e-5)
    assert torch.equal(moved.R, cal.R) and torch.equal(moved.pitch, cal.pitch)


@pytest.fixture(scope="module")
def off_centre():
    """A street whose principal point is 17 px off the centre (the renderer's imperfection, fixed seed)."""
    return render_scene(8, (640, 480), RenderConfig(kinds={"street": 1.0}, centre_std=0.04))


def test_a_given_principal_point_is_the_calibrations(off_centre):
    pp = tuple(off_centre.K[:2, 2].tolist())
    centred = calibrate(off_centre.image, weights="none")
    given = calibrate(off_centre.image, weights="none", priors={"principal_point": pp})
    assert given.K[:2, 2].tolist() == pytest.approx(list(pp), abs=1e-3)
    assert given.principal_point_std.tolist() == [0.0, 0.0] and centred.principal_point_std is None
    assert given.to_dict()["cx"] == pytest.approx(pp[0], abs=1e-3)
    assert torch.allclose(given.horizon[None], horizon_from_zenith(given.K[None], given.zenith[None]), atol=1e-5)


def test_convention_a_given_principal_point_follows_the_segments():
    # the same lines moved by t, with the principal point moved by t: the same camera, moved by t
    parser = NeuralGeometricParser()
    segments, mask = detect_segments(render_scene(8, (320, 240)).image)
    t = torch.tensor([7.0, -4.0])
    images = torch.zeros(1, 3, 240, 320)
    alone = parser(images, segments, mask)
    moved = parser(images, segments + t, mask, priors=Priors(principal_point=(159.5 + 7.0, 119.5 - 4.0)))
    # one computation but for the rounding of +t and -t on the coordinates
    assert torch.allclose(moved.R, alone.R, atol=1e-4)
    assert torch.allclose(moved.K[:, :2, 2], alone.K[:, :2, 2] + t, atol=1e-4)
    assert torch.allclose(moved.focal, alone.focal, rtol=1e-4)


def test_estimated_principal_points_come_nearer_the_truth():
    config = RenderConfig(kinds={"street": 0.6, "indoor": 0.4}, centre_std=0.025)
    errors, offsets = [], []
    for seed in range(20, 30):  # ten scenes: one photo's estimate may miss, their median may not
        scene = render_scene(seed, (480, 360), config)
        est = calibrate(scene.image, weights="none", priors={"principal_point": "estimate"})
        errors.append(float((est.K[:2, 2].double() - scene.K[:2, 2]).norm()))
        offsets.append(float((scene.K[:2, 2] - torch.tensor([239.5, 179.5], dtype=torch.float64)).norm()))
        assert est.principal_point_std.shape == (2,) and bool((est.principal_point_std > 0).all())
    # the centre's error is the offset itself; the estimate halves it here (0.51), 0.75 leaves room
    assert torch.tensor(errors).median() < 0.75 * torch.tensor(offsets).median()


def test_bad_principal_points_are_refused():
    with pytest.raises(ValueError, match="principal_point"):
        calibrate(torch.rand(3, 64, 64), priors={"principal_point": (1.0,)})
    with pytest.raises(ValueError, match="principal_point"):
        calibrate(torch.rand(3, 64, 64), priors={"principal_point": "guess"})
