"""TrustSettings.centre_std: an uncertain principal point widens the standard deviations, and only them."""

import json
import math
from dataclasses import replace

import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.errors import ConfigError
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline import trust as confidence
from ngp_kornia.pipeline.trust import TRUST_FILE, TrustModel, principal_point_terms
from ngp_kornia.training.synth.render import render_scene

STDS = ("pitch_std", "roll_std", "fov_v_std")


@pytest.fixture(scope="module")
def image():
    return render_scene(3, size=(320, 240)).image


@pytest.mark.parametrize("bad", [-0.01, 0.26, math.nan, math.inf, "0.02", True, None])
def test_bad_values_are_a_clear_config_error(bad):
    with pytest.raises(ConfigError, match="centre_std must be"):
        ParserConfig().replace(centre_std=bad)


def test_default_is_for_unknown_cameras_and_zero_is_allowed():
    assert ParserConfig().trust.centre_std == 0.025
    assert ParserConfig().replace(centre_std=0).trust.centre_std == 0
    assert ParserConfig().replace(centre_std=0.25).trust.centre_std == 0.25


def test_standard_deviations_grow_with_the_option_and_answers_stay(image):
    out = [calibrate(image, config=ParserConfig().replace(centre_std=v)) for v in (0.0, 0.01, 0.02, 0.05)]
    for name in STDS:
        values = [float(getattr(o, name)) for o in out]
        assert values == sorted(values) and values[0] < values[-1], (name, values)
    for o in out[1:]:
        a, b = out[0].to_dict(), o.to_dict()
        for name in STDS:
            a.pop(name), b.pop(name)
        assert a == b  # the answer, its score and its confidence do not change


def test_zero_gives_the_line_term_alone(image):
    """With the option at 0 the standard deviations are those of a model without the principal-point term."""
    plain = replace(TrustModel.load(), principal_point=dict.fromkeys(("pitch", "roll", "fov_v"), 0.0))
    cal = calibrate(image, config=ParserConfig().replace(centre_std=0.0))
    shipped = confidence._shipped
    try:
        confidence._shipped = lambda: plain
        same = calibrate(image, config=ParserConfig().replace(centre_std=0.05))
    finally:
        confidence._shipped = shipped
    for name in STDS:
        assert float(getattr(cal, name)) == pytest.approx(float(getattr(same, name)), rel=1e-6)


def test_known_focal_keeps_the_fov_std_at_zero(image):
    scene = render_scene(3, size=(320, 240))
    config = ParserConfig().replace(centre_std=0.05)
    out = calibrate(image, config=config, priors={"focal": float(scene.focal)})
    assert float(out.fov_v_std) == 0.0 and float(out.pitch_std) > 0


def test_principal_point_terms():
    level, steep = torch.tensor([0.0]), torch.tensor([45.0])
    assert principal_point_terms(0.0, torch.tensor([500.0]), 480, level) is None
    terms = principal_point_terms(0.02, torch.tensor([480.0, 960.0]), 480, torch.tensor([0.0, 45.0]))
    assert terms["pitch"][0].item() == pytest.approx(math.degrees(0.02 * 480 / 480))
    assert terms["pitch"][1].item() == pytest.approx(terms["pitch"][0].item() / 2)  # longer lens, smaller angle
    # roll: nothing for a level camera, tan(pitch) times the ray's turn otherwise
    assert terms["roll"][0].item() == 0.0 and terms["roll"][1].item() == pytest.approx(terms["pitch"][1].item())
    assert principal_point_terms(0.02, torch.tensor([480.0]), 480, -steep)["roll"].item() > 0
    # d fov_v / d f at f = H / 2 (90 degrees): H / (f^2 + H^2 / 4) = 2 / H per pixel
    fov = principal_point_terms(0.02, torch.tensor([240.0]), 480, level)["fov_v"]
    assert fov.item() == pytest.approx(math.degrees(0.02 * 480 * 2 / 480))


def test_shipped_gains_and_old_files(tmp_path):
    model = TrustModel.load()
    assert all(model.principal_point[k] > 0 for k in ("pitch", "roll", "fov_v"))
    data = json.loads(TRUST_FILE.read_text())
    data.pop("principal_point")
    old = tmp_path / "trust.json"
    old.write_text(json.dumps(data))
    assert TrustModel.load(old).principal_point == {"pitch": 0.0, "roll": 0.0, "fov_v": 0.0}
