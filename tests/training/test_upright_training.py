"""Training the orientation and structure check: the thumbnails (cached, three shapes, structure-free ones among
them), the turns and the photometric changes, a Lightning fast_dev_run, export to a weights file and back."""

import cv2
import lightning as L
import numpy as np
import pytest
import torch

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.nets.upright import CLASSES, UprightNet
from ngp_kornia.nets.weights import load_network, network_name
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.upright_calibration import fit_temperature, turned_logits
from ngp_kornia.training.upright_data import UprightDataModule, collate_thumbs, sample_keys, thumb_of
from ngp_kornia.training.upright_module import UprightModule, photometric, random_crops, turned


def test_keys_put_a_structure_free_image_every_nth():
    keys = sample_keys(10, 500, 7, 3)
    assert keys == ["r10", "r11", "s500", "r12", "r13", "s501", "r14"]


def test_thumbnails_are_cached_and_labelled(tmp_path):
    dm = UprightDataModule(cache_dir=str(tmp_path), train_size=3, val_size=2, test_size=2, structureless_every=3)
    dm.prepare_data()
    dm.setup("fit")
    ds = dm.datasets["train"].parts[0]  # renders and structure-free images only: no photo folder given
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
    assert net.settings() == {"size": 32, "width": 4, "temperature": 1.0} and len(CLASSES) == 5


def _photos(root, count=24):
    """A folder of small photos, sky blue above and brown below (upright), in two sub-folders."""
    for i in range(count):
        sub = root / ("x" if i % 2 else "y")
        sub.mkdir(parents=True, exist_ok=True)
        image = np.zeros((30 + i, 40, 3), np.uint8)
        image[: image.shape[0] // 2] = (230, 180, 120)  # BGR: sky
        image[image.shape[0] // 2 :] = (40, 80, 120)
        cv2.imwrite(str(sub / f"{i}.png"), image)
    return root


def test_held_back_photos_validate_in_every_turn_and_the_train_part_trains(tmp_path):
    root = _photos(tmp_path / "photos", 40)
    dm = UprightDataModule(cache_dir=str(tmp_path / "cache"), train_size=2, val_size=3, test_size=1,
                           structureless_every=2, photos=str(root), photo_repeats=2, store_size=80)
    dm.prepare_data()
    dm.setup("fit")
    train, val = dm.datasets["train"], dm.datasets["val"]
    held = split_photos(root, "calibrate")
    assert held and len(val) == 4 * len(held) + 3 and len(train) == 2 * len(split_photos(root, "train")) + 2
    batch = collate_thumbs([val[i] for i in range(len(val))])
    assert batch.real.tolist() == [True] * (4 * len(held)) + [False] * 3  # the photos first, each four times
    assert torch.equal(batch.thumbs[0], batch.thumbs[3]) and batch.thumbs.shape[-1] == 80
    assert int(collate_thumbs([train[i] for i in range(len(train))]).real.sum()) == len(train) - 2


class _Given(torch.nn.Module):
    """A stand-in network whose logits are given."""

    size = 16

    def __init__(self, logits):
        super().__init__()
        self.logits = logits

    def forward(self, thumbs):
        return self.logits


def test_a_real_photo_teaches_its_turn_and_nothing_of_its_structure():
    from ngp_kornia.training.upright_data import ThumbBatch

    logits = torch.randn(4, 5, requires_grad=True)
    module = UprightModule(_Given(logits))
    module.log = lambda *a, **k: None
    flags = torch.ones(4, dtype=torch.bool)
    loss = module._step(ThumbBatch(torch.rand(4, 3, 16, 16), flags, flags), "val", 0)  # turned 0, 1, 2, 3
    loss.backward()
    assert torch.count_nonzero(logits.grad[:, 4]) == 0  # the structure-free logit is left alone
    expected = torch.nn.functional.cross_entropy(logits[:, :4].detach(), torch.arange(4))
    assert float(loss.detach()) == pytest.approx(float(expected), rel=1e-6)


def test_random_crops_keep_the_size_and_the_whole_image_is_the_thumbnail():
    thumbs = torch.rand(6, 3, 32, 32)
    crops = random_crops(thumbs, 16, 0.5, torch.Generator().manual_seed(0))
    assert crops.shape == (6, 3, 16, 16) and not torch.allclose(crops, random_crops(thumbs, 16, 1.0))
    assert torch.allclose(random_crops(thumbs, 16, 1.0), torch.nn.functional.avg_pool2d(thumbs, 2))


def test_the_temperature_is_found_again():
    gen = torch.Generator().manual_seed(0)
    scores = torch.randn(4000, 4, generator=gen) * 3.0
    turns = torch.multinomial(torch.softmax(scores / 2.5, -1), 1, generator=gen)[:, 0]  # calibrated at T = 2.5
    assert fit_temperature(scores, turns) == pytest.approx(2.5, rel=0.1)


def test_held_back_photos_are_read_in_four_turns(tmp_path):
    root = _photos(tmp_path / "photos", 4)
    names = split_photos(root, "train")[:2]
    net = UprightNet(size=16, width=4).eval()
    logits, turns = turned_logits(net, root, names)
    assert logits.shape == (4 * len(names), 5) and turns.tolist() == [0, 1, 2, 3] * len(names)
