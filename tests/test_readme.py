"""The README's layer example runs as written, and its loss reaches the shipped FSNet."""

import re
from pathlib import Path

import torch

from ngp_kornia.training.synth.render import render_scene

README = Path(__file__).resolve().parent.parent / "README.md"


def test_layer_example_runs_and_trains_fsnet():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    example = next(b for b in blocks if "class UprightClassifier" in b)
    placeholder = "images = torch.rand(2, 3, 480, 640)"
    assert placeholder in example
    # real scenes instead of the placeholder noise, and keep the model to look at its gradients
    example = example.replace(placeholder, "images = scenes").replace(
        "UprightClassifier()(", "(model := UprightClassifier())("
    )
    scenes = torch.stack([torch.from_numpy(render_scene(s, (320, 240)).image).permute(2, 0, 1) for s in (1, 4)])
    namespace = {"scenes": scenes.float() / 255}
    exec(compile(example, "README.md", "exec"), namespace)
    grads = [p.grad for p in namespace["model"].parser.fsnet.parameters() if p.grad is not None]
    assert grads and sum(float(g.abs().sum()) for g in grads) > 0, "the loss did not reach FSNet"
