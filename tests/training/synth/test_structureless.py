"""The structure-free images: every kind draws, is repeatable from its seed, and holds no long straight edges."""

import numpy as np
import pytest

from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.structureless import KINDS, structureless_image


@pytest.mark.parametrize("kind", KINDS)
def test_each_kind_is_an_rgb_image_repeatable_from_its_seed(kind):
    img = structureless_image(3, (160, 120), kind)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert np.array_equal(img, structureless_image(3, (160, 120), kind))
    assert not np.array_equal(img, structureless_image(4, (160, 120), kind))
    assert img.std() > 3.0  # not a flat image: flat ones are refused before any check


@pytest.mark.parametrize("kind", KINDS)
def test_no_long_straight_edges(kind):
    # what the parser could build an answer on: a render's buildings give segments of a tenth of the width and more
    segments, mask = detect_segments(structureless_image(11, (320, 240), kind))
    lengths = (segments[0, :, 0] - segments[0, :, 1]).norm(dim=-1)[mask[0]]
    assert int((lengths > 0.2 * 320).sum()) <= 2


def test_an_unknown_kind_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown structure-free kind 'bricks'"):
        structureless_image(0, (32, 32), "bricks")
