"""Training the line-evidence network: the data (cached, labelled, padded), the figures it is judged by, a Lightning
fast_dev_run, export to a weights file and back."""

import lightning as L
import numpy as np
import pytest
import torch

from ngp_kornia.nets import FEATURE_NAMES, LineEvidenceNet
from ngp_kornia.nets.weights import load_network, network_name
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.evidence_data import LineBatch, LineEvidenceDataModule, LineSample, collate_lines
from ngp_kornia.training.evidence_module import LineEvidenceModule, evidence_figures, structure_offset


@pytest.fixture(scope="module")
def datamodule(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    return LineEvidenceDataModule(cache_dir=str(cache), train_size=4, val_size=2, test_size=2, size=(320, 240),
                                  batch_size=2)


def test_samples_are_labelled_and_cached(datamodule):
    datamodule.prepare_data()
    datamodule.setup("fit")
    ds = datamodule.datasets["train"]
    assert len(list(ds.cache.glob("*.npz"))) == 8  # train, val and test seeds
    s = ds[0]
    n = len(s.segments)
    assert n > 0 and s.features.shape == (n, len(FEATURE_NAMES)) and s.structure.shape == s.direction.shape == (n,)
    assert ((s.structure >= 0) & (s.structure <= 1)).all() and set(np.unique(s.direction)) <= {0, 1, 2}
    again = ds[0]
    assert np.array_equal(s.features, again.features)


def test_collate_pads_every_array():
    a = LineSample(np.ones((3, 2, 2), np.float32), np.ones((3, len(FEATURE_NAMES)), np.float32),
                   np.ones(3, np.float32), np.zeros(3, np.int64), np.array([10, 20]))
    b = LineSample(np.ones((1, 2, 2), np.float32), np.ones((1, len(FEATURE_NAMES)), np.float32),
                   np.zeros(1, np.float32), np.ones(1, np.int64), np.array([10, 20]))
    batch = collate_lines([a, b])
    assert batch.mask.tolist() == [[True, True, True], [True, False, False]]
    assert batch.features[1, 1:].abs().sum() == 0 and batch.direction[1].tolist() == [1, 2, 2]


def _batch(structure, direction, mask):
    n = mask.shape[1]
    return LineBatch(torch.zeros(1, n, 2, 2), mask, torch.zeros(1, n, len(FEATURE_NAMES)), structure, direction,
                     torch.tensor([[10, 10]]))


def test_figures_count_what_they_say():
    mask = torch.tensor([[True, True, True, True, False]])
    batch = _batch(torch.tensor([[1.0, 0.8, 0.0, 0.2, 1.0]]), torch.tensor([[0, 1, 2, 2, 0]]), mask)
    logits = torch.tensor([[3.0, -5.0, -5.0, 0.0, 9.0]])  # kept, dropped, dropped, kept, padding
    direction = torch.tensor([[[5.0, 0, 0], [5.0, 0, 0], [0, 0, 5.0], [0, 0, 5.0], [5.0, 0, 0]]])
    f = evidence_figures(logits, direction, batch)
    assert f["keep_structure"] == 0.5 and f["drop_other"] == 0.5 and f["direction_accuracy"] == 0.5


def test_fast_dev_run_trains_and_exports(datamodule, tmp_path):
    module = LineEvidenceModule(LineEvidenceNet(width=8, context=4))
    before = [p.detach().clone() for p in module.parameters()]
    trainer = L.Trainer(fast_dev_run=True, accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.fit(module, datamodule)
    assert any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))
    assert torch.isfinite(trainer.callback_metrics["train/loss"])
    assert "val/keep_structure" in trainer.callback_metrics or "val/drop_other" in trainer.callback_metrics
    assert float(module.net.structure_offset) != 0.0  # set after the validation
    ckpt = tmp_path / "m.ckpt"
    trainer.save_checkpoint(ckpt)
    weights = export_checkpoint(ckpt, tmp_path / "evidence.pt")
    assert network_name(weights) == "LineEvidenceNet"
    net = load_network(weights, "LineEvidenceNet")
    assert net.settings() == {"width": 8, "context": 4} and not net.training
    # the file holds the trained network: the same logits as the module's own
    images = torch.rand(1, 3, 60, 80)
    segments = torch.tensor([[[[5.0, 5.0], [70.0, 8.0]], [[40.0, 2.0], [41.0, 55.0]]]])
    mask = torch.ones(1, 2, dtype=torch.bool)
    module.net.eval()
    with torch.no_grad():
        assert torch.equal(net(images, segments, mask)[0], module.net(images, segments, mask)[0])
    assert float(net.structure_offset) == float(module.net.structure_offset)


def test_the_offset_keeps_the_share_asked_for():
    lo, hi, bins = LineEvidenceModule.HISTOGRAM
    logits = torch.randn(1000, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 3 + 1
    counts = torch.zeros(bins, dtype=torch.float64)
    counts.index_add_(0, ((logits - lo) / (hi - lo) * bins).long(), torch.ones_like(logits))
    for share in (0.5, 0.9, 0.97):
        offset = structure_offset(counts, LineEvidenceModule.HISTOGRAM, 0.1, share)
        kept = float((torch.sigmoid(logits + offset) >= 0.1).double().mean())
        assert share <= kept <= share + 0.002  # the bins are 1e-3 wide: a logit or two more may fall in the first


def test_keep_share_must_be_a_share():
    with pytest.raises(ValueError, match="keep_share"):
        LineEvidenceModule(LineEvidenceNet(width=4, context=2), keep_share=1.5)


def test_a_render_without_its_object_map_is_refused():
    from ngp_kornia.training.evidence_data import label_render
    from ngp_kornia.training.synth.render import render_scene

    with pytest.raises(ValueError, match="objects=True"):
        label_render(render_scene(0, (160, 120)))


def test_init_weights_start_from_the_shipped_evidence():
    from ngp_kornia.nets.weights import shipped_weights

    shipped = load_network(shipped_weights("evidence"), "LineEvidenceNet")
    module = LineEvidenceModule(LineEvidenceNet(**shipped.settings()), init_weights="evidence")
    for name, tensor in shipped.state_dict().items():
        assert torch.equal(module.net.state_dict()[name], tensor)
    fresh = LineEvidenceModule(LineEvidenceNet(**shipped.settings()))
    assert not all(torch.equal(fresh.net.state_dict()[k], v) for k, v in shipped.state_dict().items())


def test_init_weights_of_other_settings_is_one_clear_error():
    from ngp_kornia.errors import ConfigError
    from ngp_kornia.nets.weights import shipped_weights

    width = load_network(shipped_weights("evidence"), "LineEvidenceNet").settings()["width"]
    with pytest.raises(ConfigError, match="width"):
        LineEvidenceModule(LineEvidenceNet(width=width + 8), init_weights="evidence")
