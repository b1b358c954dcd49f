"""Radial distortion: its estimate from chained segments, calibrate()'s ``k1`` (given or estimated), the exports that
carry it and rectify()'s undistortion."""

import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.geometry import Camera, distort_points, rectify, upright_homography
from ngp_kornia.geometry.lens import coefficient_from_pseudo, coefficient_to_pseudo
from ngp_kornia.metrics import horizon_error
from ngp_kornia.pipeline.distortion import estimate_distortion
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.render import RenderConfig, render_scene

SIZE = (640, 480)


def _scene(k1: float, seed: int = 5):
    """A street through a lens of distortion ``k1`` (exactly), and the same street through a pinhole."""
    config = RenderConfig(kinds={"street": 1.0}, k1_range=(k1, k1)) if k1 else RenderConfig(kinds={"street": 1.0})
    return render_scene(seed, SIZE, config)


@pytest.fixture(scope="module")
def bent():
    return _scene(-0.25)


def test_units_convert_both_ways():
    lam, focal = torch.tensor([-0.1, 0.05]), torch.tensor([300.0, 700.0])
    assert torch.allclose(coefficient_to_pseudo(coefficient_from_pseudo(lam, focal, 480, 640), focal, 480, 640), lam)


def test_estimate_straightens_a_bent_photo_and_leaves_a_straight_one(bent):
    centre = torch.tensor([[319.5, 239.5]])
    segments, mask = detect_segments(bent.image)
    lam = estimate_distortion(segments, mask, centre, 480, 640)
    k1 = coefficient_from_pseudo(lam, bent.focal[None].float(), 480, 640)
    # 0.01 on the renders' median; 0.03 is the accuracy the estimate is held to
    assert float(k1) == pytest.approx(-0.25, abs=0.03)
    straight = _scene(0.0)
    segments, mask = detect_segments(straight.image)
    assert float(estimate_distortion(segments, mask, centre, 480, 640)) == 0.0  # no gain, no distortion


def test_calibrate_estimates_k1_and_its_horizon_improves(bent):
    plain = calibrate(bent.image, weights="none")
    est = calibrate(bent.image, weights="none", priors={"k1": "estimate"})
    assert plain.k1 is None and plain.to_dict()["distortion"] == [0.0] * 5
    assert float(est.k1) == pytest.approx(-0.25, abs=0.05)  # the focal length's error adds to the estimate's

    def error(cal):
        return float(horizon_error(cal.horizon[None].double(), bent.horizon[None], 480, 640)[0])

    assert error(est) < error(plain)
    row = est.to_dict()
    assert row["k1"] == pytest.approx(float(est.k1)) and row["distortion"][0] < -0.1
    K, dist = est.to_opencv()
    assert dist[0] == pytest.approx(row["distortion"][0]) and dist[2] == dist[3] == 0.0
    assert est.to_colmap()["model"] == "RADIAL"
    with pytest.raises(ValueError, match="drop"):
        est.to_colmap("SIMPLE_PINHOLE")


def test_a_given_k1_is_the_calibrations(bent):
    given = calibrate(bent.image, weights="none", priors={"k1": -0.25, "focal": float(bent.focal)})
    assert float(given.k1) == pytest.approx(-0.25, rel=1e-5)
    unknown_focal = calibrate(bent.image, weights="none", priors={"k1": -0.25})
    assert float(unknown_focal.k1) == pytest.approx(-0.25, rel=1e-5)
    with pytest.raises(ValueError, match="k1"):
        calibrate(bent.image, weights="none", priors={"k1": 3.0})


def test_rectify_undistorts_lines_back_to_straight(bent):
    # the pinhole image's pixels, distorted, are where rectify() with k1 reads them: its identity warp undistorts
    K, k1 = bent.K[None].float(), torch.tensor([-0.25])
    image = torch.from_numpy(bent.image).permute(2, 0, 1)[None].float() / 255
    camera = Camera.from_matrix(K, torch.eye(3)[None], torch.tensor([[480, 640]]), k1)
    out, applied = rectify(image, torch.eye(3)[None], size=(480, 640), crop="valid", camera=camera)
    assert out.shape == (1, 3, 480, 640) and float(out.amax()) > 0
    # a point of the output, taken back through the applied homography and distorted, is a pixel of the input
    point = torch.tensor([[[320.0, 240.0]]])
    back = torch.linalg.solve(applied, torch.cat([point, torch.ones(1, 1, 1)], -1)[..., None])[..., 0]
    source = distort_points(back[..., :2] / back[..., 2:], K, k1)
    assert bool(((source >= 0) & (source <= torch.tensor([639.0, 479.0]))).all())
    # an upright warp of a calibrated bent photo keeps the shapes sane
    cal = calibrate(bent.image, weights="none", priors={"k1": "estimate"})
    H = upright_homography(cal.K[None], cal.R[None])
    upright, _ = rectify(image, H, crop="valid", camera=cal.camera.apply(lambda t: t[None]))
    assert upright.shape[-2] > 100 and upright.shape[-1] > 100
    with pytest.raises(ValueError, match="one batched Camera"):
        rectify(image, H, camera=cal.camera)


@pytest.mark.parametrize("k1", [-0.5, -1.0])
def test_strong_barrel_distortion_gives_a_finite_answer(bent, k1):
    """With k1 <= -0.5 the image's corners lie beyond the division model's reach, where undistorted points are
    thrown far out; the call still answers, with finite numbers."""
    result = calibrate(bent.image, priors={"k1": k1})
    assert bool(torch.isfinite(result.K).all()) and bool(torch.isfinite(result.horizon).all())
