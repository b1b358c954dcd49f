"""The views benchmark of the orientation check (benchmarks/upright_views.py): each view's reading, mapped back to
the turns of the thumbnail it was made from, must name that thumbnail's turn for a reader that reads turns exactly.
A wrong mapping (a mirror taken as upright for a quarter turn, a turn added where it should be taken away) would
average readings of different turns and blur every figure the benchmark reports."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[2]


def _views():
    spec = importlib.util.spec_from_file_location("upright_views", ROOT / "benchmarks" / "upright_views.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class EdgeReader(nn.Module):
    """Reads the turn from which edge of the thumbnail is bright: an upright thumbnail is bright along its top edge,
    a quarter turn counter-clockwise puts that edge on the left, a half turn at the bottom, three quarters on the
    right (a mirror image keeps the top and bottom and swaps left and right, as it swaps 90 and 270 degrees)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        edges = [x[..., 0, :], x[..., :, 0], x[..., -1, :], x[..., :, -1]]
        scores = torch.stack([e.mean((1, 2)) for e in edges], -1) * 10.0
        return torch.cat([scores, torch.zeros(len(x), 1)], -1)


def test_every_view_reads_back_the_true_turn():
    views = _views()
    thumbs = torch.zeros(3, 3, 16, 16)
    thumbs[:, :, 0, :] = 1.0  # bright sky along the top edge
    thumbs[1, :, :, 5] = 0.3  # something that is not symmetric, so a mirror image differs
    logits = views.view_logits(EdgeReader(), thumbs)  # (N, 4 turns, 4 rotations, 2 mirrors, 5)
    read = logits[..., :4].argmax(-1)
    assert bool((read == torch.arange(4)[None, :, None, None]).all())


def test_averaging_one_view_is_that_view():
    views = _views()
    logits = torch.randn(2, 4, 4, 2, 5)
    one = views.combine(logits, [(0, False)], "log")
    assert torch.allclose(one, torch.log_softmax(logits[:, :, 0, 0], -1))
    both = views.combine(logits, [(0, False), (1, True)], "prob")
    mean = (torch.softmax(logits[:, :, 0, 0], -1) + torch.softmax(logits[:, :, 1, 1], -1)) / 2
    assert torch.allclose(both.exp(), mean, atol=1e-6)
