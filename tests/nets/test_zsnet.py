"""ZSNet: shapes, padding invariance, the line-feature ablation, weights files."""

import pytest
import torch

from ngp_kornia.nets.weights import WeightsError, load_network, save_network
from ngp_kornia.nets.zsnet import ZSNet, canonical_homogeneous


def inputs(b=2, n_lines=20, n_z=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (
        torch.randn(b, n_lines, 3, generator=g),
        torch.ones(b, n_lines, dtype=torch.bool),
        torch.randn(b, n_z, 3, generator=g),
    )


@pytest.mark.parametrize("b", [1, 3])
def test_one_logit_per_candidate(b):
    lines, mask, z = inputs(b)
    assert ZSNet(width=8)(lines, mask, z).shape == (b, 12)


def test_padding_does_not_change_any_output():
    torch.manual_seed(0)
    net = ZSNet(width=8).eval()
    lines, mask, z = inputs(1)
    padded = torch.cat([lines, 100 * torch.randn(1, 7, 3)], 1)
    pmask = torch.cat([mask, torch.zeros(1, 7, dtype=torch.bool)], 1)
    assert torch.allclose(net(lines, mask, z), net(padded, pmask, z), atol=1e-6)


def test_candidates_are_scored_independently_of_each_other():
    net = ZSNet(width=8).eval()
    lines, mask, z = inputs(1)
    assert torch.allclose(net(lines, mask, z)[:, :5], net(lines, mask, z[:, :5]), atol=1e-6)


def test_sign_of_homogeneous_inputs_does_not_matter():
    net = ZSNet(width=8).eval()
    lines, mask, z = inputs(1)
    assert torch.allclose(net(lines, mask, z), net(-lines, mask, -3 * z), atol=1e-5)


def test_global_line_feature_changes_scores_and_ablation_ignores_lines():
    lines, mask, z = inputs(1)
    full, ablated = ZSNet(width=8).eval(), ZSNet(width=8, use_line_feature=False, use_support=False).eval()
    other = torch.randn_like(lines)
    assert not torch.allclose(full(lines, mask, z), full(other, mask, z))
    assert torch.allclose(ablated(lines, mask, z), ablated(other, mask, z))


def test_no_lines_gives_finite_scores():
    lines, _, z = inputs(1)
    out = ZSNet(width=8)(lines, torch.zeros(1, 20, dtype=torch.bool), z)
    assert bool(torch.isfinite(out).all())


def test_canonical_homogeneous_fixes_sign_and_scale():
    v = torch.tensor([[1.0, -2.0, 2.0]])
    assert torch.allclose(canonical_homogeneous(v, 1), torch.tensor([[-1.0, 2.0, -2.0]]) / 3)


def test_weights_round_trip_and_clear_errors(tmp_path):
    net = ZSNet(width=8, use_line_feature=False)
    path = save_network(net, tmp_path / "z.pt", net.settings(), {"note": "test"})
    loaded = load_network(path, "ZSNet")
    lines, mask, z = inputs(1)
    assert torch.allclose(loaded(lines, mask, z), net.eval()(lines, mask, z))
    with pytest.raises(WeightsError, match="not found"):
        load_network(tmp_path / "missing.pt", "ZSNet")
    (tmp_path / "bad.pt").write_bytes(path.read_bytes()[:500])
    with pytest.raises(WeightsError, match="bad.pt is not a readable weights file"):
        load_network(tmp_path / "bad.pt", "ZSNet")
    with pytest.raises(WeightsError, match="expected 'FSNet'"):
        load_network(path, "FSNet")
    torch.save(
        {"format": "ngp-kornia-weights", "network": "ZSNet", "settings": {"width": 16}, "state_dict": net.state_dict()},
        tmp_path / "m.pt",
    )
    with pytest.raises(WeightsError, match="m.pt does not fit a ZSNet"):
        load_network(tmp_path / "m.pt", "ZSNet")
    torch.save({"a": 1}, tmp_path / "other.pt")
    with pytest.raises(WeightsError, match="not an ngp-kornia weights file"):
        load_network(tmp_path / "other.pt", "ZSNet")


def test_support_counts_the_lines_through_a_candidate():
    # three lines through (0, 5), one elsewhere; candidates: that point and a point no line passes
    lines = torch.tensor([[[1.0, 0.0, 0.0], [1.0, 0.2, -1.0], [1.0, -0.2, 1.0], [0.0, 1.0, 3.0]]])
    z = torch.tensor([[[0.0, 5.0, 1.0], [3.0, 0.0, 1.0]]])
    support = ZSNet(width=8).support(lines, torch.ones(1, 4, dtype=torch.bool), z)
    assert support[0, 0].tolist() == pytest.approx([0.75, 0.75, 0.75], abs=1e-3)
    assert float(support[0, 1].max()) < 0.01
