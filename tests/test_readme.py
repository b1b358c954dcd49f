"""The README is true: every Python block in it runs as written, one after the other (on rendered stand-ins for the
photos it names), its layer example's loss reaches the shipped FSNet, and it stays a guide of at most 20 KB."""

import re
from pathlib import Path

import cv2
import pytest
import torch

from ngp_kornia.training.synth.render import render_scene

README = Path(__file__).resolve().parent.parent / "README.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)


def _photo(path: Path, seed: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(render_scene(seed, (640, 480)).image, cv2.COLOR_RGB2BGR))


def test_readme_is_a_guide_of_at_most_20_kb():
    assert README.stat().st_size <= 20 * 1024


@pytest.mark.slow
def test_every_python_block_runs_in_order(tmp_path, monkeypatch):
    """The blocks as a reader runs them, in a folder holding the photos they name (renders: the package ships no
    photograph)."""
    pytest.importorskip("pycolmap")
    _photo(tmp_path / "photo.jpg", 2)
    _photo(tmp_path / "photos" / "b.jpg", 5)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    blocks = _blocks()
    assert len(blocks) >= 4
    for index, block in enumerate(blocks):
        exec(compile(block, f"README.md, Python block {index + 1}", "exec"), namespace)
    assert (tmp_path / "database.db").is_file()  # the COLMAP block wrote its database


def test_layer_example_runs_and_trains_fsnet():
    example = next(b for b in _blocks() if "class UprightClassifier" in b)
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
