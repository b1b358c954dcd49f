"""draw_calibration's text sits on a dark box and a key of the segment colours is drawn."""

import numpy as np
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.viz import LEGEND, draw_calibration


@pytest.fixture(scope="module")
def drawn():
    scene = render_scene(2, (640, 480))
    cal = calibrate(scene.image, weights="none")
    white = np.full_like(scene.image, 255)  # the hardest background for white text
    segments = np.array([[[100.0, 100.0], [100.0, 300.0]], [[300.0, 200.0], [400.0, 210.0]]])
    return draw_calibration(white, cal, segments), draw_calibration(white, cal, vps=False)


def _has(region: np.ndarray, colour) -> bool:
    return bool((np.abs(region.astype(int) - np.array(colour)).sum(-1) < 30).any())


def test_label_is_white_on_a_dark_box(drawn):
    image = drawn[0]
    corner = image[:24, :200]
    assert np.median(corner) < 80  # the box: dark even on a white image
    assert (corner.min(-1) > 200).sum() > 50  # the white text on it


def test_legend_shows_every_colour_in_the_bottom_left(drawn):
    with_segments, without = drawn
    key = with_segments[-110:, :130]
    assert np.median(key) < 80
    for _, colour in LEGEND:
        assert _has(key, colour), colour
    # without segments or VPs only the horizon is drawn, so only the horizon is explained
    small = without[-110:, :130]
    assert _has(small, LEGEND[3][1]) and not _has(small, LEGEND[0][1])


def test_the_input_is_left_alone():
    image = np.full((120, 160, 3), 200, np.uint8)
    draw_calibration(image, calibrate(torch.rand(3, 120, 160), weights="none"))
    assert (image == 200).all()
