"""The parser as a layer inside a larger model: rectify with the estimated camera, then a small CNN; a loss on the
CNN's output trains the parser's FSNet too. The README shows the same model."""

import torch
from torch import nn

from ngp_kornia.geometry import rectify, upright_homography
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.pipeline import NeuralGeometricParser, ParserConfig, SegmentSettings
from ngp_kornia.pipeline.segments import detect_segments
from ngp_kornia.training.synth.render import render_scene


class UprightClassifier(nn.Module):
    """Calibrate, warp the photo upright, classify it."""

    def __init__(self, parser: NeuralGeometricParser, classes: int = 4) -> None:
        super().__init__()
        self.parser = parser
        self.cnn = nn.Sequential(nn.Conv2d(3, 8, 3, stride=2), nn.ReLU(), nn.AdaptiveAvgPool2d(1), nn.Flatten())
        self.head = nn.Linear(8, classes)

    def forward(self, images, segments=None, mask=None):
        cal = self.parser(images, segments, mask)
        upright, _ = rectify(images, upright_homography(cal.K, cal.R), size=(96, 128))
        return self.head(self.cnn(upright))


def test_a_loss_after_rectification_trains_the_parser():
    torch.manual_seed(0)
    fsnet = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)
    model = UprightClassifier(NeuralGeometricParser(ParserConfig().replace(num_scored=8), fsnet=fsnet))
    scenes = [render_scene(seed, (160, 120)) for seed in (1, 4)]
    images = torch.stack([torch.from_numpy(s.image).permute(2, 0, 1).float() / 255 for s in scenes])
    # LSD once, outside the training loop
    segments, mask = detect_segments(images, SegmentSettings(working_size=160, min_length=8.0, max_segments=256))

    logits = model(images, segments, mask)
    loss = nn.functional.cross_entropy(logits, torch.tensor([0, 3]))
    loss.backward()

    fsnet_grads = [p.grad for p in model.parser.fsnet.parameters() if p.grad is not None]
    assert fsnet_grads and all(bool(torch.isfinite(g).all()) for g in fsnet_grads)
    assert sum(float(g.abs().sum()) for g in fsnet_grads) > 0  # the loss reaches the frame scorer
    assert float(model.cnn[0].weight.grad.abs().sum()) > 0

    before = [p.detach().clone() for p in model.parser.fsnet.parameters()]
    torch.optim.SGD(model.parameters(), lr=0.1).step()
    after = list(model.parser.fsnet.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, after, strict=True))
