"""The reader of the turn from the line segments: its geometry, its output and its place in the orientation check."""

import math

import numpy as np
import pytest
import torch

from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet, line_turn_features, turn_segments
from ngp_kornia.nets.weights import load_network, save_network
from ngp_kornia.pipeline import NeuralGeometricParser
from ngp_kornia.pipeline.upright_check import fuse_line_reading
from ngp_kornia.pipeline.weight_sets import check_weights


@pytest.mark.parametrize("turns", [0, 1, 2, 3])
def test_turned_segments_lie_where_rot90_puts_their_pixels(turns):
    height, width = 5, 8
    ends = torch.tensor([[[1.0, 2.0], [6.0, 4.0]]])
    image = np.zeros((height, width), int)
    image[2, 1], image[4, 6] = 1, 2  # the two ends, (x, y) -> row y, column x
    turned = np.rot90(image, turns)
    seg, h, w = turn_segments(ends, height, width, turns)
    assert (h, w) == turned.shape
    for end, mark in zip(seg[0].tolist(), (1, 2), strict=True):
        assert turned[int(end[1]), int(end[0])] == mark


def test_features_are_zero_for_padding_and_finite_elsewhere():
    seg = torch.tensor([[[[10.0, 5.0], [10.0, 5.0]], [[5.0, 20.0], [60.0, 22.0]], [[0.0, 0.0], [1.0, 1.0]]]])
    feats = line_turn_features(seg, torch.tensor([[True, True, False]]), 48, 64)
    assert feats.shape == (1, 3, 11) and bool(torch.isfinite(feats).all())
    assert feats[0, 2].abs().sum() == 0


def test_a_segment_at_the_same_place_reads_alike_in_a_portrait_and_a_landscape_image():
    # the midpoint is scaled by each axis' own size: the aspect ratio is no cue to the turn
    for height, width in ((40, 64), (64, 40)):
        x, y = 0.75 * width - 0.5, 0.25 * height - 0.5  # three quarters across, a quarter down
        seg = torch.tensor([[[[x - 5.0, y], [x + 5.0, y]]]])
        feats = line_turn_features(seg, torch.ones(1, 1, dtype=torch.bool), height, width)
        assert torch.allclose(feats[0, 0, :2], torch.tensor([0.5, -0.5]))


def test_reading_is_a_distribution_and_uniform_without_segments():
    net = UprightLinesNet(width=8, members=2).eval()
    seg = torch.rand(2, 6, 2, 2) * 50
    mask = torch.tensor([[True] * 6, [False] * 6])
    read = net(seg, mask, 60, 80)
    assert torch.allclose(read.exp().sum(-1), torch.ones(2))
    assert torch.allclose(read[1], torch.full((4,), -math.log(4.0)))


def test_bad_shapes_are_refused_with_the_expected_ones():
    with pytest.raises(ValueError, match=r"segments \(B, N, 2, 2\) and mask \(B, N\)"):
        UprightLinesNet(4, 1)(torch.zeros(1, 3, 4), torch.ones(1, 3, dtype=torch.bool), 10, 10)
    with pytest.raises(ValueError, match="positive"):
        UprightLinesNet(0, 1)


def test_weights_file_round_trip_keeps_the_reading_and_the_fusion(tmp_path):
    net = UprightLinesNet(width=8, members=2).eval()
    net.temperature.fill_(1.5)
    net.fusion.copy_(torch.tensor([0.8, 0.9]))
    path = save_network(net, tmp_path / "lines.pt", net.settings())
    back = load_network(path, "UprightLinesNet")
    seg, mask = torch.rand(1, 5, 2, 2) * 30, torch.ones(1, 5, dtype=torch.bool)
    assert torch.equal(back(seg, mask, 40, 40), net(seg, mask, 40, 40))
    assert back.fusion.tolist() == pytest.approx([0.8, 0.9])


def test_fusion_keeps_the_structure_free_reading_and_sums_to_one():
    net = UprightLinesNet(width=4, members=1)
    net.fusion.copy_(torch.tensor([0.8, 0.9]))
    probs = torch.tensor([[0.5, 0.2, 0.1, 0.1, 0.1]])
    fused = fuse_line_reading(net, probs, torch.log(torch.tensor([[0.1, 0.6, 0.2, 0.1]])))
    assert fused[0, 4] == pytest.approx(0.1) and float(fused.sum()) == pytest.approx(1.0)
    assert fused[0, 1] > probs[0, 1]  # the lines read a quarter turn: it gains


def test_every_weight_set_has_the_shipped_reader():
    assert "UprightLinesNet" in {type(net).__name__ for net in check_weights("none")}


def test_the_parser_fuses_the_lines_reading_only_where_asked(scene_with_lines):
    image, segments, mask = scene_with_lines
    torch.manual_seed(0)
    upright, lines = UprightNet().eval(), UprightLinesNet(width=8, members=1).eval()
    with torch.no_grad():
        lines.readers[0].head[-1].bias.copy_(torch.tensor([0.0, 4.0, 0.0, 0.0]))  # reads a quarter turn
    alone = NeuralGeometricParser(upright=upright)(image, segments, mask)
    off = NeuralGeometricParser({"upright.lines": False}, upright=upright, upright_lines=lines)(image, segments, mask)
    fused = NeuralGeometricParser(upright=upright, upright_lines=lines)(image, segments, mask)
    assert torch.equal(off.upright, alone.upright) and torch.equal(off.confidence, alone.confidence)
    assert bool((fused.upright < alone.upright).all())


@pytest.fixture
def scene_with_lines():
    image = torch.zeros(1, 3, 96, 128)
    image[..., 20:76, 30:50] = 1.0
    image[..., 30:70, 70:110] = 0.5
    segments = torch.tensor([[[[30.0, 20.0], [30.0, 75.0]], [[50.0, 20.0], [50.0, 75.0]], [[70.0, 30.0], [110.0, 34.0]],
                              [[70.0, 70.0], [110.0, 66.0]], [[70.0, 30.0], [70.0, 70.0]]]])  # fmt: skip
    return image, segments, torch.ones(1, 5, dtype=torch.bool)
