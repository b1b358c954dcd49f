"""Training the orientation and structure check: the thumbnails (cached, three shapes, structure-free ones among
them), the turns and the photometric changes, a Lightning fast_dev_run, export to a weights file and back."""

import lightning as L
import numpy as np
import pytest
import torch

from ngp_kornia.nets.upright import CLASSES, UprightNet
from ngp_kornia.nets.weights import load_network, network_name
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.upright_data import UprightDataModule, sample_keys, thumb_of
from ngp_kornia.training.upright_module import UprightModule, photometric, turned


def test_keys_put_a_structure_free_image_every_nth():
    keys = sample_keys(10, 500, 7, 3)
    assert keys == ["r10", "r11", "s500", "r12", "r13", "s501", "r14"]


def test_thumbnails_are_cached_and_labelled(tmp_path):
    dm = UprightDataModule(cache_dir=str(tmp_path), train_size=3, val_size=2, test_size=2, structureless_every=3)
    dm.prepare_data()
    dm.setup("fit")
    ds = dm.datasets["train"]
    assert len(list(ds.cache.glob("*.npz"))) == 7
    structured = [bool(ds[i].structured[0]) for i in range(3)]
    assert structured == [True, True, False]
    assert ds[0].thumb.shape == (3, 64, 64) and ds[0].thumb.dtype == np.uint8
    assert np.array_equal(ds[0].thumb, ds.compute(ds.keys[0]).thumb)


def test_turns_are_those_of_np_rot90():
    thumbs = torch.rand(4, 3, 8, 8)
    out = turned(thumbs, torch.tensor([0, 1, 2, 3]))
    for k in range(4):
        expected = np.rot90(thumbs[k].numpy(), k, axes=(1, 2))
        assert np.array_equal(out[k].numpy(), expected)


def test_thumbnail_of_a_turned_image_is_the_turned_thumbnail():
    # the cache holds upright thumbnails and training turns them: that must equal the thumbnail of the turned image
    rgb = (np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8)
    small = torch.from_numpy(thumb_of(rgb, 16)).float()
    turned_small = torch.from_numpy(thumb_of(np.rot90(rgb).copy(), 16)).float()
    assert torch.allclose(turned(small[None], torch.tensor([1]))[0], turned_small, atol=1.0)


def test_photometric_changes_stay_in_range_and_change_the_look():
    thumbs = torch.rand(8, 3, 16, 16)
    out = photometric(thumbs, torch.Generator().manual_seed(0))
    assert out.shape == thumbs.shape and float(out.min()) >= 0 and float(out.max()) <= 1
    assert not torch.allclose(out, thumbs, atol=0.05)


@pytest.mark.slow
def test_fast_dev_run_trains_and_exports(tmp_path):
    dm = UprightDataModule(cache_dir=str(tmp_path / "cache"), train_size=4, val_size=4, test_size=4, batch_size=4,
                           size=32, structureless_every=2)
    module = UprightModule(UprightNet(size=32, width=4))
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        default_root_dir=str(tmp_path))
    before = [p.detach().clone() for p in module.net.parameters()]
    trainer.fit(module, datamodule=dm)
    assert any(not torch.equal(a, b) for a, b in zip(before, module.net.parameters(), strict=True))
    ckpt = tmp_path / "last.ckpt"
    trainer.save_checkpoint(ckpt)
    out = export_checkpoint(ckpt, tmp_path / "upright.pt")
    assert network_name(out) == "UprightNet"
    net = load_network(out, "UprightNet")
    assert net.settings() == {"size": 32, "width": 4} and len(CLASSES) == 5
