"""The parser's trace: the stages it returns are the ones its answer came from, and asking for them changes nothing."""

import pytest
import torch

from ngp_kornia.api import load_parser
from ngp_kornia.geometry import pseudo_focal, structure_tensor, topk_weighted_average
from ngp_kornia.geometry.frames import select_frames, top_frames
from ngp_kornia.nets.fsnet_inputs import frame_scores
from ngp_kornia.nets.zsnet import zenith_estimate, zenith_weights_from_scores
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig, ParserTrace
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def images():
    scenes = [render_scene(seed, (320, 240)) for seed in (2, 5)]
    return torch.stack([torch.from_numpy(s.image).permute(2, 0, 1).float() / 255 for s in scenes])


def _same(a: Calibration, b: Calibration) -> None:
    for name in Calibration.FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or torch.equal(x, y), name


@pytest.mark.parametrize("weights", ["none", "zsnet", "fsnet", "full"])
def test_trace_leaves_the_answer_unchanged(images, weights):
    parser = load_parser(weights, ParserConfig().replace(num_scored=8))
    with torch.no_grad():
        plain = parser(images)
        traced, trace = parser(images, return_trace=True)
    assert isinstance(trace, ParserTrace)
    _same(plain, traced)
    assert (trace.scored_index is None) == (parser.fsnet is None) == (trace.fsnet_scores is None)


@pytest.mark.parametrize("weights", ["none", "full"])
def test_trace_shapes_and_the_answer_it_gives(images, weights):
    # without the horizon refinement, which may move the answer off the frames (another focal length, say)
    cfg = ParserConfig().replace(num_scored=8, top_k=4, **{"horizon.refine": False})
    parser = load_parser(weights, cfg)
    with torch.no_grad():
        cal, t = parser(images, return_trace=True)
    B, N = t.mask.shape
    Z, F = t.zenith_candidates.shape[1], t.frames.focal.shape[1]
    assert t.segments.shape == (B, N, 2, 2) and t.lines.shape == (B, N, 3) and t.horizontal.shape == (B, N)
    assert t.zenith_lines.shape[:2] == t.zenith_lines_ok.shape and t.zenith_lines.shape[2] == 3
    assert t.zenith_ok.shape == t.zenith_weights.shape == (B, Z) and t.zenith_estimate.shape == (B, 3)
    assert t.horizontal_vps.shape[:2] == t.horizontal_ok.shape
    assert t.manhattan.shape == (B, F) and bool((t.manhattan[~t.frames.valid] == 0).all())
    assert not bool(t.horizontal[~t.mask].any())
    # the zenith estimate is Eq. 10-12 of the traced weights
    torch.testing.assert_close(t.zenith_estimate, zenith_estimate(t.zenith_candidates, t.zenith_weights))
    if parser.fsnet is None:
        assert t.final_frames is t.frames and torch.equal(t.final_scores, t.manhattan)
    else:
        K = cfg.scoring.num_scored
        assert t.scored_index.shape == t.fsnet_scores.shape == t.final_scores.shape == (B, K)
        assert torch.equal(t.scored_index, top_frames(t.frames, t.manhattan, K))
        kept = select_frames(t.frames, t.scored_index)
        assert torch.equal(kept.focal, t.final_frames.focal)
        expected = frame_scores(t.fsnet_scores, t.manhattan.gather(1, t.scored_index), kept.valid)
        assert torch.equal(t.final_scores, expected)
    # the final answer: score, top-k focal (Eq. 23) and zenith come from the traced final frames and scores
    assert torch.equal(cal.score, t.final_scores.amax(-1))
    assert torch.equal(t.best, t.final_scores.argmax(-1))
    w = t.top_k_weights
    assert bool(((w > 0).sum(-1) <= cfg.scoring.top_k).all())
    valid = t.final_frames.valid.any(-1)
    assert bool(valid.all()), "the scenes have lines: every image has a valid frame"
    torch.testing.assert_close(w.sum(-1), torch.ones(B))
    focal, _ = topk_weighted_average(t.final_scores, t.final_frames.focal, cfg.scoring.top_k, t.final_frames.valid)
    torch.testing.assert_close(cal.focal, focal * pseudo_focal(240, 320))
    torch.testing.assert_close((w * t.final_frames.focal).sum(-1), focal)
    st = (w[..., None, None] * structure_tensor(t.final_frames.zenith)).sum(1)
    z = torch.linalg.eigh(st).eigenvectors[..., -1]
    # the pseudo camera is K = diag(f, f, 1): the up direction of the zenith z is K^-1 z
    up = torch.nn.functional.normalize(z / torch.stack([focal, focal, torch.ones_like(focal)], -1), dim=-1)
    cos = (cal.up * up).sum(-1).abs()
    assert bool((cos > 1 - 1e-5).all())


def test_trace_with_given_segments_keeps_them():
    seg = torch.tensor([[[[10.0, 10.0], [10.0, 90.0]], [[30.0, 10.0], [32.0, 90.0]], [[5.0, 50.0], [90.0, 52.0]]]])
    mask = torch.tensor([[True, True, False]])
    cal, t = NeuralGeometricParser()(torch.zeros(1, 3, 100, 100), seg, mask, return_trace=True)
    assert torch.equal(t.segments[mask], seg[mask]) and torch.equal(t.mask, mask)  # padding is zeroed
    assert bool(torch.isfinite(cal.focal).all())


def test_eq12_weights_match_the_thresholding_of_the_paper():
    scores = torch.tensor([[0.9, 0.6, 0.4, 0.8], [0.1, 0.2, 0.3, 0.4]])
    valid = torch.tensor([[True, True, True, False], [True, True, False, True]])
    w = zenith_weights_from_scores(scores, valid, threshold=0.5)
    assert w.tolist()[0] == pytest.approx([0.9, 0.6, 0.0, 0.0])
    assert w.tolist()[1] == [1.0, 1.0, 0.0, 1.0]  # nothing above delta_c: uniform on the valid ones
