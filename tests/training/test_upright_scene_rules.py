"""The study that chose the orientation check's doubt power (benchmarks/upright_scene_rules.py) simulates the check on
cached readings. Its simulation must give what the parser gives for the same readings: the same confidence and the
same reported turns as the package's own chain (fusion, prior, pitch cue, ``apply_upright``), or the rule it chose
would be chosen for a check that does not exist."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.nets.weights import load_network
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.pipeline.upright_check import apply_upright, fuse_line_reading, weigh_by_pitch, with_prior

ROOT = Path(__file__).resolve().parents[2]


def _study():
    sys.path.insert(0, str(ROOT / "benchmarks"))  # it imports the studies beside it
    try:
        path = ROOT / "benchmarks" / "upright_scene_rules.py"
        spec = importlib.util.spec_from_file_location("upright_scene_rules", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return module


def _readings(photos: int, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    thumb = torch.log_softmax(3.0 * torch.randn(photos, 4, 5, generator=g, dtype=torch.float64), -1)
    lines = torch.log_softmax(2.0 * torch.randn(photos, 4, 4, generator=g, dtype=torch.float64), -1)
    pitch = 40.0 * torch.rand(photos, 4, generator=g, dtype=torch.float64) - 20.0
    conf = torch.rand(photos, 4, generator=g, dtype=torch.float64)
    return {"names": [f"p{i}" for i in range(photos)], "thumb": thumb, "lines": lines, "pitch": pitch, "conf": conf}


@pytest.mark.parametrize("rule", [
    {"prior": 0.75, "sure": 0.9, "doubt": 0.5, "power": 1.0},
    {"prior": 0.75, "sure": 0.9, "doubt": 0.5, "power": 2.0},
    {"prior": 0.5, "sure": 0.6, "doubt": 0.7, "power": 3.0},
])  # fmt: skip
def test_the_simulated_check_is_the_parsers(rule):
    study, data = _study(), _readings(5)
    net = load_network(ROOT / "ngp_kornia" / "weights" / "upright_lines.pt", "UprightLinesNet").eval()
    simulated = study.decide(data, rule, net)
    off = ParserConfig().replace(**{"upright.enabled": False})
    answer = calibrate(torch.rand(20, 3, 32, 32, generator=torch.Generator().manual_seed(1)), config=off).to(
        torch.float64
    )
    answer = type(answer)(**{**answer.__dict__, "valid": torch.ones(20, dtype=torch.bool),
                             "confidence": data["conf"].reshape(-1)})  # fmt: skip
    probs = fuse_line_reading(net, data["thumb"].exp().reshape(-1, 5), data["lines"].reshape(-1, 4))
    probs = weigh_by_pitch(with_prior(probs, rule["prior"]), data["pitch"].reshape(-1), 15.0)
    parsed = apply_upright(answer, probs, rule["sure"], True, 60.0, rule["doubt"], rule["power"])
    assert torch.allclose(simulated["confidence"], parsed.confidence, atol=1e-9)
    assert torch.equal(simulated["reported"], parsed.turned != 0)
    assert torch.equal(simulated["doubted"], parsed.upright < rule["doubt"])
    assert bool(simulated["reported"].any()) and bool(simulated["doubted"].any())  # both rules exercised
