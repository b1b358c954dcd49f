"""The confidence and standard deviations every answer carries, and the focal-length prior."""

import json
import math

import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.geometry.frames import frames_from_vps
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline import frame_search as search_module
from ngp_kornia.pipeline.priors import Priors
from ngp_kornia.pipeline.trust import TRUST_FILE, TrustModel
from ngp_kornia.pipeline.trust_features import TrustFeatures, line_residual
from ngp_kornia.training.synth.render import render_scene

TRUST_FIELDS = ("confidence", "pitch_std", "roll_std", "fov_v_std")


@pytest.fixture(scope="module")
def scene():
    return render_scene(3, size=(320, 240))


def test_noise_and_blank_images_have_low_confidence():
    g = torch.Generator().manual_seed(0)
    noise = torch.rand(2, 3, 240, 320, generator=g)
    blobs = torch.nn.functional.interpolate(torch.rand(1, 3, 12, 16, generator=g), size=(240, 320), mode="bicubic")
    for image in (noise, blobs.clamp(0, 1), torch.zeros(1, 3, 240, 320), torch.ones(1, 3, 240, 320)):
        out = calibrate(image)
        assert bool((out.confidence < 0.1).all()), out.confidence


def test_a_clean_scene_is_trusted_more_than_noise():
    clean = calibrate(render_scene(0, size=(320, 240)).image)  # horizon error 0.004 image heights
    noise = calibrate(torch.rand(3, 240, 320, generator=torch.Generator().manual_seed(1)))
    assert float(clean.confidence) > 0.5 > float(noise.confidence)


def test_trust_fields_shapes_ranges_and_json(scene):
    image = torch.from_numpy(scene.image).permute(2, 0, 1).float().div(255)
    batch = calibrate(torch.stack([image, torch.zeros_like(image)]))
    for name in TRUST_FIELDS:
        value = getattr(batch, name)
        assert value.shape == (2,) and bool(torch.isfinite(value).all()) and bool((value >= 0).all())
    assert bool((batch.confidence <= 1).all())
    assert not bool(batch.valid[1]) and float(batch.confidence[1]) == 0.0 and float(batch.pitch_std[1]) == 90.0
    row = json.loads(json.dumps(batch[0].to_dict()))
    assert all(isinstance(row[name], float) for name in TRUST_FIELDS)
    assert batch.to(torch.float64).confidence.dtype == torch.float64


def test_standard_deviations_follow_the_spread_of_the_top_frames():
    model = TrustModel.load()
    for name in ("pitch", "roll", "fov_v"):
        assert model.std[name][1] > 0  # a wider spread of the top frames gives a wider standard deviation


def test_coefficients_file_must_match_the_inputs(tmp_path):
    data = json.loads(TRUST_FILE.read_text())
    data["inputs"] = data["inputs"][:-1]
    bad = tmp_path / "trust.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="inputs"):
        TrustModel.load(bad)


def test_known_focal_is_kept_exactly_and_fov_std_is_zero(scene):
    out = calibrate(scene.image, priors={"focal": scene.focal})
    assert float(out.focal) == pytest.approx(float(scene.focal), rel=1e-5)
    assert float(out.fov_v_std) == 0.0
    by_fov = calibrate(scene.image, priors={"fov_v": scene.fov_v})
    assert float(by_fov.focal) == pytest.approx(float(scene.focal), rel=1e-4)
    no_frame = calibrate(torch.zeros(3, 64, 64), priors={"focal": 50.0})
    assert float(no_frame.focal) == pytest.approx(50.0)  # no frame: the prior


@pytest.mark.parametrize("priors", [{"focal": -3.0}, {"focal": math.nan}, {"fov_v": 0.0}, {"fov_v": 190.0}])
def test_bad_prior_is_a_clear_error(priors):
    with pytest.raises(ValueError, match="focal|fov_v"):
        calibrate(torch.rand(3, 64, 64), priors=priors)


def test_convention_prior_focal_in_pseudo_camera_units():
    assert Priors().focal_in_units(480, 640) is None
    assert Priors(focal=640.0).focal_in_units(480, 640) == pytest.approx(2.0)
    assert Priors(fov_v=2 * math.degrees(math.atan(0.375))).focal_in_units(480, 640) == pytest.approx(2.0)


def test_known_focal_builds_frames_from_pairs_that_disagree_with_it():
    # zenith and horizontal VP of a camera with f = 2 (pseudo units), pitch 20 deg; the horizontal VP is nudged off
    # the horizon, so the pair alone gives a wrong focal length, or none
    f, pitch = 2.0, math.radians(20.0)
    up = torch.tensor([0.0, -math.cos(pitch), math.sin(pitch)])
    side = torch.tensor([math.cos(0.3), 0.0, math.sin(0.3)])
    side = side - (side @ up) * up
    K = torch.diag(torch.tensor([f, f, 1.0]))
    zenith, horizontal = K @ up, K @ side + torch.tensor([0.0, 0.3, 0.0])
    free = frames_from_vps(zenith[None, None], horizontal[None, None], torch.ones(1, 1, dtype=torch.bool))
    known = frames_from_vps(zenith[None, None], horizontal[None, None], torch.ones(1, 1, dtype=torch.bool), focal=f)
    assert bool(known.valid.all()) and float(known.focal) == f
    assert not bool(free.valid.all()) or abs(float(free.focal) - f) > 0.05
    # the zenith is kept; the frame's rotation is orthonormal with the true up vector as its down axis (negated)
    R = known.R[0, 0]
    assert torch.allclose(R.T @ R, torch.eye(3), atol=1e-5)
    assert torch.allclose(-R[:, 1], up / up.norm(), atol=1e-5)


def test_prior_changes_how_frames_are_built_not_only_which_survive(scene):
    image = torch.from_numpy(scene.image).permute(2, 0, 1).float().div(255)[None]
    narrow = NeuralGeometricParser(
        ParserConfig().replace(focal_range=(1.0, 1.0 + 1e-6))
    )  # filtering alone: almost nothing
    known = NeuralGeometricParser(ParserConfig().replace(focal_range=(1.0, 1.0 + 1e-6)))
    assert not bool(narrow(image).valid[0])
    assert bool(known(image, priors=Priors(focal=float(scene.focal))).valid[0])


def test_values_shared_by_the_parser_give_what_each_step_computes_alone(scene, monkeypatch):
    """The parser computes the segments' lines, lengths and top-k weights once for the frame scores, FSNet's inputs
    and the trust fields; each step computing them again from its own arguments gives the same answer bit for bit."""
    image = torch.from_numpy(scene.image).permute(2, 0, 1).float().div(255)
    shared = calibrate(image).to_dict()
    attach = search_module.attach_trust
    monkeypatch.setattr(search_module, "attach_trust", lambda *args, shared=None, **kwargs: attach(*args, **kwargs))
    prepare = FSNet.prepare_inputs
    monkeypatch.setattr(FSNet, "prepare_inputs", lambda self, *args: prepare(self, *args[:4]))
    alone = calibrate(image).to_dict()
    for name, value in shared.items():
        assert torch.equal(value, alone[name]) if isinstance(value, torch.Tensor) else value == alone[name], name


def test_the_parsers_horizon_search_gives_what_the_trust_fields_compute_alone(scene, monkeypatch):
    """The parser hands its horizon search to the trust fields; without it they run the same search on the answer.
    With the refinement off the answer is the frame search's, so both give the same fields bit for bit."""
    image = torch.from_numpy(scene.image).permute(2, 0, 1).float().div(255)
    config = ParserConfig().replace(refine=False)
    given = calibrate(image, config=config).to_dict()
    attach = search_module.attach_trust
    monkeypatch.setattr(search_module, "attach_trust", lambda *a, refinement=None, **kw: attach(*a, **kw))
    alone = calibrate(image, config=config).to_dict()
    for name in TRUST_FIELDS:
        assert given[name] == alone[name], name


def _segments_towards(vp: torch.Tensor, turn_deg: float, n: int = 40) -> torch.Tensor:
    """(1, n, 2, 2) segments of length 40 px at random places, each pointing at the pixel ``vp`` turned by
    +-``turn_deg`` about its midpoint (alternating signs)."""
    g = torch.Generator().manual_seed(5)
    mids = torch.rand(n, 2, generator=g, dtype=torch.float64) * torch.tensor([600.0, 440.0]) + 20
    ray = vp[None] - mids
    angle = torch.atan2(ray[:, 1], ray[:, 0]) + math.radians(turn_deg) * torch.tensor([1.0, -1.0]).repeat(n // 2)
    half = 20 * torch.stack([torch.cos(angle), torch.sin(angle)], -1)
    return torch.stack([mids - half, mids + half], 1)[None]


def test_line_residual_measures_how_far_the_segments_miss_their_vps():
    vps = torch.tensor([[[2000.0, 250.0, 1.0], [330.0, -5000.0, 1.0], [-1500.0, 230.0, 1.0]]], dtype=torch.float64)
    mask = torch.ones(1, 40, dtype=torch.bool)
    for turn in (0.0, 0.5, 1.0):
        seg = _segments_towards(vps[0, 0, :2], turn)
        assert float(line_residual(vps, seg, mask)[0]) == pytest.approx(turn, abs=0.05)  # a few lie nearer another VP
    one = vps[:, :1].expand(-1, 3, -1)  # the three VPs at one place: every segment 5 deg off all of them
    far = _segments_towards(vps[0, 0, :2], 5.0)  # beyond RESIDUAL_INLIER: no inliers, residual 0
    assert float(line_residual(one, far, mask)[0]) == 0.0


def test_noisier_lines_widen_the_standard_deviations_in_proportion():
    model = TrustModel.load()
    assert model.residual_exponent == 1.0
    clean = {name: torch.tensor([0.2]) for name in TrustFeatures.__dataclass_fields__}
    noisy = dict(clean, line_residual=torch.tensor([2 * 0.2 + 0.05]))  # (residual + 0.05) doubled
    conf = torch.tensor([0.8])
    a, b = model.stds(TrustFeatures(**clean), conf), model.stds(TrustFeatures(**noisy), conf)
    for name in ("pitch", "roll", "fov_v"):
        assert float(b[name] / a[name]) == pytest.approx(2.0, rel=1e-5)
