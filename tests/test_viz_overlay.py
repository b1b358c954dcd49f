"""draw_calibration reads at a glance: the photo undimmed with thin segments, and below it (never over it) a strip of
the numbers and a key of every colour and shape drawn."""

import numpy as np
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.viz import AXIS_COLOURS, HORIZON_COLOUR, LEGEND, draw_calibration
from ngp_kornia.viz_key import KeyEntry, key_strip


@pytest.fixture(scope="module")
def level():
    """A level camera's answer on a 640 x 480 image: the horizon crosses the image at mid height."""
    from ngp_kornia.pipeline.answer import calibration_from_camera

    K = torch.tensor([[[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]])
    R = torch.eye(3)[None]
    return calibration_from_camera(K, R, torch.ones(1), torch.ones(1, dtype=torch.bool), 480, 640)[0]


SEGMENTS = np.array([[[100.0, 100.0], [100.0, 300.0]], [[300.0, 200.0], [400.0, 210.0]]])


def _has(region: np.ndarray, colour) -> bool:
    return bool((np.abs(region.astype(int) - np.array(colour)).sum(-1) < 30).any())


def test_the_photo_is_not_dimmed_and_the_key_sits_below_it(level):
    photo = np.full((480, 640, 3), 200, np.uint8)
    drawn = draw_calibration(photo, level, SEGMENTS)
    assert drawn.shape[1] == 640 and 480 + 40 < drawn.shape[0] < 480 + 160
    assert (drawn[:60, :60] == 200).all()  # no dark box over the photo (it once sat over the horizon's left end)
    strip = drawn[480:]
    assert np.median(strip) < 60 and (strip.min(-1) > 200).sum() > 200  # white words on a dark band
    # the key never covers the drawing: the photo's rows are what is drawn without it
    assert np.array_equal(drawn[:480], draw_calibration(photo, level, SEGMENTS, key=False))
    for x in (0, 639):  # both ends of the horizon are drawn, in its colour
        assert _has(drawn[235:245, x : x + 1], HORIZON_COLOUR)


def test_segments_are_thin_and_in_their_axis_colour(level):
    drawn = draw_calibration(np.full((480, 640, 3), 200, np.uint8), level, SEGMENTS, key=False)
    row = drawn[200, 90:110]  # across the vertical segment at x = 100
    wide = (np.abs(row.astype(int) - np.array(AXIS_COLOURS[1])).sum(-1) < 60).sum()
    assert 1 <= wide <= 2  # one pixel (two where antialiased), not the 2-3 of before


def test_the_key_explains_every_colour_and_shape_drawn(level):
    photo = np.full((480, 640, 3), 200, np.uint8)
    full = draw_calibration(photo, level, SEGMENTS)[480:]
    for _, colour in LEGEND:
        assert _has(full, colour), colour
    bare = draw_calibration(photo, level, vps=False)[480:]  # no segments, no VPs: horizon and up arrow only
    assert _has(bare, HORIZON_COLOUR) and not _has(bare, LEGEND[0][1]) and not _has(bare, LEGEND[2][1])
    assert bare.shape[0] < full.shape[0]  # the rings and border pointers of the VPs are explained too


def test_the_strip_wraps_to_narrow_images_and_keeps_its_words_inside():
    entries = [KeyEntry(name, colour, "line") for name, colour in LEGEND]
    for width in (1024, 200, 120):
        strip = key_strip(width, ["focal 500 px", "towards a vanishing point off the image"], entries)
        assert strip.shape[1] == width and strip.shape[0] < 400
        assert (strip[:, -2:] == strip[0, 0]).all()  # nothing drawn into the last columns: no word cut at the edge


def test_an_invalid_answer_says_so(level):
    from dataclasses import replace

    photo = np.full((240, 320, 3), 200, np.uint8)
    small = calibrate(photo)
    invalid = draw_calibration(photo, replace(small, valid=torch.tensor(False)))[240:]
    assert not np.array_equal(invalid, draw_calibration(photo, replace(small, valid=torch.tensor(True)))[240:])


def test_the_input_is_left_alone():
    image = np.full((120, 160, 3), 200, np.uint8)
    draw_calibration(image, calibrate(torch.rand(3, 120, 160), weights="none"))
    assert (image == 200).all()


def test_a_render_is_drawn_at_its_size_with_the_strip_below():
    scene = render_scene(2, (320, 240))
    drawn = draw_calibration(scene.image, calibrate(scene.image, weights="none"), truth=scene.to_dict())
    assert drawn.shape[1:] == (320, 3) and drawn.shape[0] > 240
