"""The parser with FSNet: frames rescored from the image, gradients from the outputs to the pixels and weights."""

import pytest
import torch

from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig, SegmentSettings
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.render import render_scene


def tiny_fsnet(**kwargs) -> FSNet:
    torch.manual_seed(0)
    return FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64, **kwargs).eval()


@pytest.fixture(scope="module")
def scene():
    r = render_scene(5, (192, 144))
    image = torch.from_numpy(r.image).permute(2, 0, 1)[None].float() / 255
    segments, mask = detect_segments(image, SegmentSettings(working_size=192, min_length=8.0, max_segments=256))
    return image, segments, mask


def test_fsnet_scores_only_the_best_frames(scene):
    image, segments, mask = scene
    parser = NeuralGeometricParser(ParserConfig().replace(num_scored=6), fsnet=tiny_fsnet())
    g = torch.Generator().manual_seed(0)
    frames, manhattan = parser.score_frames(segments, mask, 144, 192, g)
    kept, scores = parser.rescore_frames(image, segments, mask, frames, manhattan)
    assert scores.shape == (1, 6) and kept.focal.shape == (1, 6)
    # the kept frames are the six best by Manhattan score, and each final score is at most its Manhattan score
    best = manhattan.topk(6, -1).values
    assert torch.allclose(kept.focal, frames.focal.gather(1, manhattan.topk(6, -1).indices))
    assert bool((scores <= best + 1e-6).all()) and bool((scores > 0).all())


def test_without_manhattan_the_score_is_fsnet_alone(scene):
    image, segments, mask = scene
    net = tiny_fsnet()
    g = torch.Generator().manual_seed(0)
    product = NeuralGeometricParser(ParserConfig().replace(num_scored=6), fsnet=net)
    alone = NeuralGeometricParser(ParserConfig().replace(num_scored=6, use_manhattan=False), fsnet=net)
    frames, manhattan = product.score_frames(segments, mask, 144, 192, g)
    _, s_product = product.rescore_frames(image, segments, mask, frames, manhattan)
    _, s_alone = alone.rescore_frames(image, segments, mask, frames, manhattan)
    assert torch.allclose(s_product, s_alone * manhattan.topk(6, -1).values, atol=1e-6)


def test_gradients_reach_the_pixels_and_both_networks(scene):
    image, segments, mask = scene
    fsnet = tiny_fsnet()
    parser = NeuralGeometricParser(ParserConfig().replace(num_scored=8), fsnet=fsnet)
    pixels = image.clone().requires_grad_(True)
    out = parser(pixels, segments, mask)
    assert bool(out.valid.all())
    for name in ("focal", "zenith", "R", "horizon"):
        fsnet.zero_grad()
        pixels.grad = None
        getattr(out, name).sum().backward(retain_graph=True)
        assert pixels.grad is not None and bool(torch.isfinite(pixels.grad).all()), name
        assert float(pixels.grad.abs().sum()) > 0, name
        grads = [p.grad for p in fsnet.parameters() if p.grad is not None]
        assert grads and all(bool(torch.isfinite(g).all()) for g in grads), name
        assert sum(float(g.abs().sum()) for g in grads) > 0, name


def test_float64_image_with_float32_fsnet(scene):
    image, segments, mask = scene
    parser = NeuralGeometricParser(fsnet=tiny_fsnet())
    with torch.no_grad():
        out32 = parser(image, segments, mask)
        out64 = parser(image.double(), segments.double(), mask)
    assert out64.focal.dtype == torch.float64
    assert float(out64.focal[0]) == pytest.approx(float(out32.focal[0]), rel=1e-3)


def test_no_grad_inference_keeps_no_graph(scene):
    image, segments, mask = scene
    parser = NeuralGeometricParser(fsnet=tiny_fsnet())
    with torch.no_grad():
        out = parser(image.requires_grad_(False), segments, mask)
    assert not out.focal.requires_grad and not out.R.requires_grad



def test_fsnet_image_side_on_the_helper_thread_gives_the_same_answer(scene, monkeypatch):
    # with a second core, FSNet's resized image and then its trunk's output are made on the helper thread while the
    # frames are searched; the answer is the one the search gives computing them itself (one core), and a gradient
    # asked for keeps them inline
    import ngp_kornia.pipeline.frame_search as frame_search
    from ngp_kornia.pipeline.segments import line_workers

    image, segments, mask = scene
    parser = NeuralGeometricParser(fsnet=tiny_fsnet())
    with torch.inference_mode(), line_workers(2):
        threaded = parser(image, segments, mask)  # the real helper thread
    started = []
    monkeypatch.setattr(frame_search, "beside", lambda fn, *args: started.append(fn) or (lambda: fn(*args)))
    with torch.inference_mode(), line_workers(2):
        beside = parser(image, segments, mask)
    assert len(started) == 2 and started[0] == parser.fsnet.input_images  # the resize, then the image side
    with torch.inference_mode(), line_workers(1):
        inline = parser(image, segments, mask)
    assert len(started) == 2  # the call on one core started nothing
    for field in ("K", "R", "horizon", "confidence"):
        assert torch.equal(getattr(beside, field), getattr(inline, field))
        assert torch.equal(getattr(threaded, field), getattr(inline, field))
    with line_workers(2):
        assert parser._search().resize_beside(image.clone().requires_grad_()) is None
        view = frame_search.View(image, segments, mask)
        assert parser._search().image_side_beside(view) is None  # gradients on: the trunk runs in the search
