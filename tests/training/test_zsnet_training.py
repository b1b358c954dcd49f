"""ZSNet training: losses (gradcheck), a Lightning fast_dev_run on rendered data, export to a weights file."""

import lightning as L
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.metrics import zenith_error_deg
from ngp_kornia.nets.weights import load_network
from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.datamodules import RenderedDataModule
from ngp_kornia.training.losses import zenith_classification_loss, zenith_labels, zenith_localisation_loss
from ngp_kornia.training.zsnet_module import ZSNetModule


def test_labels_follow_the_angle_thresholds():
    gt = torch.tensor([[0.0, 1.0, 0.0]])
    angles = torch.deg2rad(torch.tensor([1.0, 3.0, 6.0]))
    z = torch.stack([torch.sin(angles), torch.cos(angles), torch.zeros(3)], -1)[None]
    labels, labelled = zenith_labels(z, gt, torch.ones(1, 3, dtype=torch.bool))
    assert labels.tolist() == [[1.0, 0.0, 0.0]] and labelled.tolist() == [[True, False, True]]


def test_classification_loss_ignores_unlabelled():
    logits = torch.tensor([[5.0, -5.0, 100.0]])
    labels = torch.tensor([[1.0, 0.0, 0.0]])
    loss = zenith_classification_loss(logits, labels, torch.tensor([[True, True, False]]))
    assert float(loss) < 0.01


def test_localisation_loss_gradcheck():
    g = torch.Generator().manual_seed(0)
    z = torch.randn(2, 5, 3, dtype=torch.float64, generator=g)
    gt = torch.randn(2, 3, dtype=torch.float64, generator=g)
    p = torch.rand(2, 5, dtype=torch.float64, generator=g).requires_grad_()
    mask = torch.ones(2, 5, dtype=torch.bool)
    assert torch.autograd.gradcheck(lambda s: zenith_localisation_loss(s, z, mask, gt), (p,))


def test_localisation_loss_is_zero_at_the_truth_and_grows_away():
    gt = torch.tensor([[0.0, 1.0, 0.1]])
    z = torch.tensor([[[0.0, 1.0, 0.1], [1.0, 0.0, 0.0]]])
    mask = torch.ones(1, 2, dtype=torch.bool)
    good = zenith_localisation_loss(torch.tensor([[1.0, 0.0]]), z, mask, gt)
    bad = zenith_localisation_loss(torch.tensor([[0.5, 0.5]]), z, mask, gt)
    assert float(good) < 1e-6 < float(bad)


def test_zenith_error_uses_the_true_focal():
    # points (0, 10) and (1, 10) in the pseudo camera differ by atan(1/10) / ... at focal 1
    a, b = torch.tensor([[0.0, 10.0, 1.0]]), torch.tensor([[1.0, 10.0, 1.0]])
    err = zenith_error_deg(a, b, torch.ones(1))
    expected = torch.rad2deg(
        torch.acos(torch.tensor(101.0) / (torch.tensor(101.0).sqrt() * torch.tensor(102.0).sqrt()))
    )
    assert float(err) == pytest.approx(float(expected), abs=1e-3)


@pytest.fixture(scope="module")
def datamodule(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    return RenderedDataModule(
        cache_dir=str(cache), train_size=4, val_size=2, test_size=2, size=(320, 240), batch_size=2
    )


@pytest.mark.slow
def test_fast_dev_run_trains_and_exports(datamodule, tmp_path):
    module = ZSNetModule(ZSNet(width=8))
    before = [p.detach().clone() for p in module.parameters()]
    trainer = L.Trainer(fast_dev_run=True, accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.fit(module, datamodule)
    assert any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))
    assert torch.isfinite(trainer.callback_metrics["train/loss"])
    ckpt = tmp_path / "m.ckpt"
    trainer.save_checkpoint(ckpt)
    weights = export_checkpoint(ckpt, tmp_path / "zsnet.pt")
    net = load_network(weights, "ZSNet")
    assert net.settings() == {"width": 8, "use_line_feature": True, "use_support": True}
    cal = calibrate(torch.rand(3, 64, 64), weights=str(weights))
    assert torch.isfinite(cal.focal)


def test_cache_is_written_once_and_reused(tmp_path):
    # a DataModule of its own: one a Trainer has used prepares only what that Trainer's call reads
    datamodule = RenderedDataModule(
        cache_dir=str(tmp_path), train_size=4, val_size=2, test_size=2, size=(320, 240), batch_size=2
    )
    datamodule.prepare_data()
    datamodule.setup("fit")
    ds = datamodule.datasets["train"]
    files = [ds.cache / f"{seed}.npz" for seed in ds.keys]
    assert all(f.exists() for f in files) and len(list(ds.cache.glob("*.npz"))) == 8  # train, val, test seeds
    first = ds[0]
    mtime = files[0].stat().st_mtime_ns
    again = ds[0]
    assert files[0].stat().st_mtime_ns == mtime
    assert (first.segments == again.segments).all()


@pytest.mark.slow
def test_worker_processes_give_the_same_batches_as_the_main_process(tmp_path):
    def first_val_batch(workers):
        dm = RenderedDataModule(
            cache_dir=str(tmp_path),
            train_size=2,
            val_size=4,
            test_size=1,
            size=(160, 120),
            batch_size=2,
            num_workers=workers,
        )
        dm.setup("fit")
        return next(iter(dm.val_dataloader()))

    a, b = first_val_batch(0), first_val_batch(2)
    assert torch.equal(a.segments, b.segments) and torch.equal(a.zenith, b.zenith)
