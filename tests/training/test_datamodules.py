"""Panorama-crop and manifest DataModules: ground truth carried through, and a Lightning fast_dev_run on each."""

import csv

import cv2
import lightning as L
import numpy as np
import torch

from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.datamodules import ManifestDataModule, PanoramaDataModule, RenderedDataModule
from ngp_kornia.training.scene_data import JoinedScenes, RenderedScenes
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig
from ngp_kornia.training.zsnet_module import ZSNetModule


def _panorama(path, seed):
    """A lat-long image of vertical stripes (meridians) and latitude bands: a world of verticals and horizontals."""
    rng = np.random.default_rng(seed)
    h, w = 128, 256
    img = np.full((h, w, 3), 60, np.uint8)
    for x in rng.choice(w, 24, replace=False):
        img[:, x : x + 2] = rng.integers(120, 255, 3)
    img[h // 2 + 10 :] //= 2
    cv2.imwrite(str(path), img)


def _fit(dm):
    trainer = L.Trainer(fast_dev_run=True, accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.fit(ZSNetModule(ZSNet(width=8)), dm)
    return trainer


def test_panorama_crops_train_and_split_by_panorama(tmp_path):
    folder = tmp_path / "panos"
    folder.mkdir()
    for i in range(4):
        _panorama(folder / f"p{i}.png", i)
    dm = PanoramaDataModule(str(folder), crops=2, size=(160, 120), cache_dir=str(tmp_path / "c"), batch_size=2)
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 4 and len(dm.datasets["val"]) == 2
    assert not set(dm.datasets["train"].panoramas) & set(dm.datasets["val"].panoramas)
    batch = next(iter(dm.train_dataloader()))
    # the crop's zenith is K @ up with pitch/roll inside the paper's sampling ranges
    up = torch.linalg.solve(batch.K, batch.zenith.unsqueeze(-1)).squeeze(-1)
    pitch = torch.rad2deg(torch.asin(torch.nn.functional.normalize(up, dim=-1)[:, 2].abs()))
    assert bool((pitch <= 40.0 + 1e-3).all())
    assert torch.isfinite(_fit(dm).callback_metrics["train/loss"])


def test_manifest_rows_train_with_their_ground_truth(tmp_path):
    rows = []
    for seed in range(3):
        scene = render_scene(seed, (160, 120))
        name = f"s{seed}.png"
        cv2.imwrite(str(tmp_path / name), cv2.cvtColor(scene.image, cv2.COLOR_RGB2BGR))
        rows.append(
            {
                "image": name,
                "focal_px": float(scene.focal),
                "pitch_deg": float(scene.pitch),
                "roll_deg": float(scene.roll),
            }
        )
    rows.append({"image": "s0.png", "focal_px": "", "pitch_deg": "", "roll_deg": ""})  # unlabelled: skipped
    with open(tmp_path / "m.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    dm = ManifestDataModule(
        str(tmp_path / "m.csv"), str(tmp_path / "m.csv"), cache_dir=str(tmp_path / "c"), batch_size=3
    )
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 3
    batch = next(iter(dm.val_dataloader()))
    truth = render_scene(0, (160, 120))
    assert torch.allclose(
        batch.zenith[0], torch.nn.functional.normalize(truth.zenith, dim=0).float(), atol=1e-4
    ) or torch.allclose(batch.zenith[0], -torch.nn.functional.normalize(truth.zenith, dim=0).float(), atol=1e-4)
    assert torch.isfinite(_fit(dm).callback_metrics["train/loss"])


def test_cache_digest_unchanged_by_default_hard_options(tmp_path):
    a = RenderedScenes(range(1), (160, 120), cache_dir=tmp_path)
    b = RenderedScenes(range(1), (160, 120), RenderConfig(fronto_jitter=5.0), cache_dir=tmp_path)
    c = RenderedScenes(range(1), (160, 120), RenderConfig(stairs=1.0), cache_dir=tmp_path)
    assert a.cache == b.cache != c.cache


def test_datamodule_joins_the_hard_scenes():
    dm = RenderedDataModule(
        cache_dir=None,
        train_size=2,
        val_size=1,
        test_size=1,
        size=(96, 72),
        hard_size=2,
        hard_config={"stairs": 2.0, "kinds": {"street": 1.0, "atlanta": 1.0}},
    )
    train = dm.make_datasets()["train"]
    assert isinstance(train, JoinedScenes) and len(train) == 4
    assert train.keys == [0, 1, 3_000_000, 3_000_001]
    assert train[3].K.shape == (3, 3)
    train.keys = train.keys[:3]
    assert len(train) == 3
