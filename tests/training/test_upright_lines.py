"""The line-segment orientation study (benchmarks/upright_lines.py): the turned and mirrored segments must lie where
``np.rot90`` and a left-right flip put the pixels, since every label of the study is the turn they are said to have;
a half turn must leave a segment's direction and length and negate its position; a random window must keep a segment
that lies inside it whole and drop one that lies outside."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def study(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))  # it imports its neighbours
    spec = importlib.util.spec_from_file_location("upright_lines", ROOT / "benchmarks" / "upright_lines.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _marked(height: int, width: int) -> tuple[np.ndarray, torch.Tensor]:
    """An image with two marked pixels and the segment between them."""
    image = np.zeros((height, width))
    image[1, 4], image[3, 2] = 1, 2
    return image, torch.tensor([[[[4.0, 1.0], [2.0, 3.0]]]])


@pytest.mark.parametrize("turns", [0, 1, 2, 3, 5])
def test_convention_turned_segments_follow_rot90(study, turns):
    image, seg = _marked(5, 7)
    turned, size = study.turn_segments(seg, torch.tensor([[5, 7]]), turns)
    expected = np.rot90(image, turns)
    (x0, y0), (x1, y1) = turned[0, 0].long().tolist()
    assert (expected[y0, x0], expected[y1, x1]) == (1, 2)
    assert tuple(size[0].tolist()) == expected.shape


def test_convention_mirrored_segments_follow_fliplr(study):
    image, seg = _marked(5, 7)
    (x0, y0), (x1, y1) = study.mirror_segments(seg, torch.tensor([[5, 7]]))[0, 0].long().tolist()
    assert (image[:, ::-1][y0, x0], image[:, ::-1][y1, x1]) == (1, 2)


def test_half_turn_negates_position_and_keeps_direction(study):
    seg = torch.tensor([[[[10.0, 5.0], [30.0, 25.0]], [[50.0, 40.0], [52.0, 5.0]]]])
    size = torch.tensor([[48, 64]])
    before = study.segment_features(seg, size)
    after = study.segment_features(*study.turn_segments(seg, size, 2))
    assert torch.allclose(after[..., :2], -before[..., :2], atol=1e-5)
    assert torch.allclose(after[..., 2:], before[..., 2:], atol=1e-5)


def test_window_keeps_inside_and_drops_outside(study):
    # the first segment lies inside every window of half the area or more; the second along the top edge
    seg = torch.tensor([[[[45.0, 50.0], [55.0, 50.0]], [[0.0, 1.0], [30.0, 1.0]]]])
    mask = torch.ones(1, 2, dtype=torch.bool)
    gen = torch.Generator().manual_seed(0)
    dropped = 0
    for _ in range(20):
        out, keep, size = study.crop_segments(seg, mask, torch.tensor([[100, 100]]), 0.5, gen)
        corner = seg[0, 0, 0] - out[0, 0, 0]  # the window's top-left corner in the image
        assert bool(keep[0, 0]) and torch.allclose(out[0, 0] + corner, seg[0, 0], atol=1e-4)
        assert bool(keep[0, 1]) == (corner[1] <= 1.0 and corner[0] <= 20.0)
        if keep[0, 1]:
            assert bool((out[0, 1] >= -1e-4).all()) and bool((out[0, 1, :, 0] <= size[0, 1] - 1 + 1e-4).all())
        dropped += int(~keep[0, 1])
    assert dropped > 0
