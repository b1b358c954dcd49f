"""The paired comparison: per-image AUC scores, set and pooled differences with intervals, halves, and the rule."""

import numpy as np
import pytest

from ngp_kornia.evaluation.compare import compare, comparison_table, image_scores
from ngp_kornia.evaluation.datasets import LabelledImage
from ngp_kornia.evaluation.suite import SuiteSet
from ngp_kornia.metrics import horizon_auc


def _images(n):
    return [LabelledImage(f"im{i}", f"im{i}.jpg", 480, 640) for i in range(n)]


def _records(spec, set_name, truth, errors_by_seed):
    return [
        {
            "weights": spec,
            "set": set_name,
            "truth": truth,
            "seed": s,
            "result": {"per_image": [{"horizon": e} for e in err]},
        }
        for s, err in enumerate(errors_by_seed)
    ]


def test_image_scores_average_to_the_horizon_auc():
    import torch

    errors = np.random.default_rng(0).uniform(0, 0.4, 50)
    records = _records("a", "set", "horizon", [errors])
    scores = image_scores(records, "a", "set", "horizon")
    assert scores.shape == (1, 50)
    assert float(scores.mean()) == pytest.approx(float(horizon_auc(torch.tensor(errors))), abs=1e-6)
    failed = _records("a", "set", "horizon", [[float("nan")]])
    assert image_scores(failed, "a", "set", "horizon").tolist() == [[0.0]]  # a failure counts as a miss


def test_a_clear_gain_everywhere_is_kept_and_a_loss_on_one_half_is_not():
    sets = [SuiteSet("A", {"horizon": _images(40)}), SuiteSet("B", {"horizon": _images(30)})]
    rng = np.random.default_rng(1)
    base = {s.name: rng.uniform(0.0, 0.1, (3, len(s.images))) for s in sets}
    records = [r for s in sets for r in _records("base", s.name, "horizon", base[s.name])]
    better = [r for s in sets for r in _records("better", s.name, "horizon", base[s.name] * 0.5)]
    result = compare(records + better, sets, "base", "better")
    assert result["keep"] and result["pooled"]["interval"][0] > 0
    gain = np.mean([100 * (base[s].mean() * 0.5 * 4) for s in base])  # 1 - e/0.25: half the error gains 2 e
    assert result["pooled"]["mean"] == pytest.approx(gain, rel=1e-6)
    # better on every even image of A, much worse on its odd ones: the odd half loses
    mixed_a = base["A"].copy()
    mixed_a[:, ::2] *= 0.1
    mixed_a[:, 1::2] += 0.01
    mixed = _records("mixed", "A", "horizon", mixed_a) + _records("mixed", "B", "horizon", base["B"] * 0.5)
    result = compare(records + mixed, sets, "base", "mixed")
    assert not result["keep"] and "A (odd)" in result["reason"]
    assert "pooled over the real sets" in comparison_table(result, "base", "mixed")


def test_the_same_setting_is_not_kept():
    sets = [SuiteSet("A", {"horizon": _images(20)})]
    errors = np.random.default_rng(2).uniform(0, 0.2, (2, 20))
    records = _records("x", "A", "horizon", errors) + _records("y", "A", "horizon", errors)
    result = compare(records, sets, "x", "y")
    assert result["pooled"]["mean"] == 0 and not result["keep"]
