"""The line-evidence stage in the parser: which segments the rest of the pipeline sees, and where its network
comes from."""

import pytest
import torch

from ngp_kornia import ConfigError, EvidenceSettings, ParserConfig
from ngp_kornia.api import load_parser
from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.pipeline import NeuralGeometricParser
from ngp_kornia.pipeline.evidence import apply_evidence
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def scene():
    image = torch.from_numpy(render_scene(4, (320, 240)).image).permute(2, 0, 1).float()[None] / 255
    return image, *detect_segments(image)


def _on(**kw) -> ParserConfig:
    return ParserConfig(evidence=EvidenceSettings(enabled=True, **kw))


def test_the_segments_below_keep_are_dropped_for_every_later_stage(scene):
    image, segments, mask = scene
    parser = load_parser("none", _on())
    with torch.no_grad():
        _, trace = parser(image, segments, mask, return_trace=True)
    assert trace.evidence.shape == mask.shape and bool(((trace.evidence >= 0) & (trace.evidence <= 1)).all())
    assert torch.equal(trace.detected, mask) and torch.equal(trace.mask, mask & (trace.evidence >= 0.1))
    assert 0 < int(trace.mask.sum()) < int(mask.sum())  # some dropped, most kept on a render
    assert not bool(trace.horizontal[~trace.mask].any())  # the dropped ones take no part in the candidates


def test_off_by_default_and_without_a_network_every_segment_is_kept(scene):
    image, segments, mask = scene
    for parser in (load_parser("none"), NeuralGeometricParser(_on())):
        with torch.no_grad():
            _, trace = parser(image, segments, mask, return_trace=True)
        assert trace.evidence is None and torch.equal(trace.mask, mask)


def test_keep_zero_keeps_all_and_keep_one_drops_almost_all(scene):
    image, segments, mask = scene
    net = load_parser("none").evidence
    weights, kept = apply_evidence(net, image, segments, mask, 0.0)
    assert torch.equal(kept, mask) and bool((weights[~mask] == 0).all())
    _, strict = apply_evidence(net, image, segments, mask, 1.0)
    assert int(strict.sum()) < int(mask.sum()) // 10


def test_the_weights_need_only_the_images_shape(scene):
    image, segments, mask = scene
    net = load_parser("none").evidence
    a, _ = apply_evidence(net, image, segments, mask)
    b, _ = apply_evidence(net, torch.zeros_like(image), segments, mask)
    assert torch.equal(a, b)


def test_every_weight_set_has_the_shipped_network_unless_given_its_own(tmp_path):
    from ngp_kornia.nets.weights import save_network

    for weights in ("none", "zsnet", "fsnet", "full"):
        assert isinstance(load_parser(weights).evidence, LineEvidenceNet)
    own = LineEvidenceNet(width=8, context=4)
    path = save_network(own, tmp_path / "evidence.pt", own.settings())
    parser = load_parser([path])
    assert parser.evidence.width == 8 and parser.zsnet is None and parser.fsnet is None


@pytest.mark.parametrize("keep", [-0.1, 1.5, float("nan")])
def test_keep_is_checked(keep):
    with pytest.raises(ConfigError, match="EvidenceSettings.keep"):
        EvidenceSettings(keep=keep)
