"""The focal-length prior in its three units (pixels, vertical field of view, 35 mm equivalent), the refusal of
two of them at once and of one that no camera has on the image, and the other per-call checks."""

import math

import pytest
import torch

from ngp_kornia import ConfigError, InputError, Priors, calibrate
from ngp_kornia.io import FILM_DIAGONAL_MM
from ngp_kornia.pipeline.priors import FOCAL_35MM_RANGE
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def photo():
    return render_scene(2).image  # 640 x 480


def test_two_focal_priors_are_refused_naming_both():
    for given in ({"focal": 500.0, "fov_v": 90.0}, {"focal": 500.0, "focal_35mm": 28.0},
                  {"fov_v": 50.0, "focal_35mm": 28.0}):
        with pytest.raises(InputError, match="were both given.*give one of focal="):
            Priors(**given)
    with pytest.raises(InputError, match=r"focal=500.0 and fov_v=90.0 were both given"):
        # --fov was once dropped without a word
        calibrate(torch.rand(3, 64, 64), priors={"focal": 500.0, "fov_v": 90.0})


def test_millimetres_given_as_pixels_are_refused_naming_the_mistake(photo):
    # focal=35 on a 640 x 480 photo was taken as a 163 degree field of view, valid, at confidence 0.999
    with pytest.raises(InputError, match=r"focal=35.0 px on this 640x480 image is a 163.4 degree .*millimetres.*"
                                         r"focal_35mm= \(--focal-35mm\)"):
        calibrate(photo, priors={"focal": 35.0})
    with pytest.raises(InputError, match="fov_v=170.0 degrees on this 640x480 image.*wider than any rectilinear"):
        calibrate(photo, priors={"fov_v": 170.0})
    with pytest.raises(InputError, match="narrower than a 2000 mm telephoto"):
        calibrate(photo, priors={"focal": 1e5})
    with pytest.raises(InputError, match=r"item 1 of the list: focal=35.0 px"):
        calibrate([torch.rand(3, 48, 64), photo], priors={"focal": 35.0})  # checked on each image, named in a list


def test_the_plausible_range_in_pixels_follows_the_image():
    low, high = FOCAL_35MM_RANGE
    for height, width in ((480, 640), (3000, 4000), (640, 480)):
        per_mm = math.hypot(height, width) / FILM_DIAGONAL_MM  # pixels per millimetre of a 35 mm equivalent
        Priors(focal=low * per_mm * 1.001).check_image(height, width)
        Priors(focal=high * per_mm * 0.999).check_image(height, width)
        for outside in (low * per_mm * 0.99, high * per_mm * 1.01):
            with pytest.raises(InputError):
                Priors(focal=outside).check_image(height, width)
    Priors(fov_v=90.0).check_image(480, 640)  # a wide lens, not refused


def test_focal_35mm_is_converted_with_the_image_diagonal(photo):
    assert Priors(focal_35mm=35.0).focal_pixels(480, 640) == pytest.approx(35.0 * 800.0 / FILM_DIAGONAL_MM)
    assert FILM_DIAGONAL_MM == pytest.approx(43.27, abs=0.01)
    by_mm = calibrate(photo, weights="none", priors={"focal_35mm": 28.0})
    by_px = calibrate(photo, weights="none", priors={"focal": 28.0 * 800.0 / FILM_DIAGONAL_MM})
    assert float(by_mm.focal) == pytest.approx(float(by_px.focal), rel=1e-6)
    assert float(by_mm.fov_v_std) == 0.0 and float(by_mm.pitch) == pytest.approx(float(by_px.pitch), abs=1e-4)
    assert Priors(focal_35mm=28.0).to_dict() == {"focal_35mm": 28.0}
    for bad in (2.0, 5000.0, 0.0, True, float("nan")):
        with pytest.raises(InputError, match="focal_35mm"):
            Priors(focal_35mm=bad)


def test_with_focal_replaces_the_prior_in_any_unit():
    assert Priors(focal_35mm=28.0, k1=-0.1).with_focal(500.0) == Priors(focal=500.0, k1=-0.1)


def test_a_negative_thread_count_is_an_input_error():
    with pytest.raises(InputError, match="num_threads=-1"):  # a bare ValueError once
        calibrate(torch.rand(3, 64, 64), num_threads=-1)


def test_a_setting_name_several_stages_have_names_them():
    with pytest.raises(ConfigError, match=r"did you mean evidence.enabled, polish.enabled or upright.enabled\?"):
        calibrate(torch.rand(3, 64, 64), config={"enabled": True})
    with pytest.raises(ConfigError, match=r"did you mean horizon.refine\?"):
        calibrate(torch.rand(3, 64, 64), config={"horizon.refin": False})
