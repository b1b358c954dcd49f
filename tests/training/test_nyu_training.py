"""Training on NYU-VP scenes: the samples (segments kept as the detection keeps them, the true zenith, labels from
the labelled vanishing points), the DataModules' splits and a Lightning fast_dev_run of each network."""

import lightning as L
import numpy as np
import pytest
import torch

from ngp_kornia.data import NYUVP
from ngp_kornia.nets import FEATURE_NAMES, LineEvidenceNet, ZSNet
from ngp_kornia.training.evidence_module import LineEvidenceModule
from ngp_kornia.training.nyu_data import (
    NYULines,
    NYULinesDataModule,
    NYUScenes,
    NYUScenesDataModule,
    nyu_line_labels,
    nyu_rotation,
)
from ngp_kornia.training.zsnet_module import ZSNetModule
from tests.nyu_files import write_fake_nyu


@pytest.fixture()
def nyu(tmp_path):
    return write_fake_nyu(tmp_path / "nyu", scenes=4)


def test_labels_come_from_the_labelled_vanishing_points(nyu):
    s = NYUVP(nyu).scene(0)
    structure, direction = nyu_line_labels(s.segments[:2].numpy(), s)
    assert direction.tolist() == [0, 1]  # the one at the zenith, the one at a horizontal VP
    assert structure.tolist() == [1.0, 1.0]
    far = np.array([[[100.0, 100.0], [300.0, 180.0]]], dtype=np.float32)  # points at none of them
    assert nyu_line_labels(far, s)[1].tolist() == [2] and nyu_line_labels(far, s)[0].tolist() == [0.0]


def test_rotation_has_the_true_vertical(nyu):
    s = NYUVP(nyu).scene(0)
    R = nyu_rotation(s)
    assert torch.allclose(R.T @ R, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(-R[:, 1], s.up, atol=1e-12)
    with pytest.raises(ValueError, match="no vertical"):
        nyu_rotation(NYUVP(nyu).scene(1))


def test_samples_skip_scenes_without_a_vertical(nyu):
    scenes = NYUScenes(nyu, range(4))
    assert scenes.keys == [0, 2, 3]
    sample = scenes[0]
    assert sample.segments.shape == (39, 2, 2) and tuple(sample.image_size) == (480, 640)
    assert np.allclose(sample.zenith, (NYUVP(nyu).scene(0).zenith).numpy())
    lines = NYULines(nyu, range(4))[0]
    assert lines.features.shape == (39, len(FEATURE_NAMES)) and lines.structure.shape == (39,)


@pytest.mark.parametrize("kind", ["zsnet", "evidence"])
def test_fast_dev_run(nyu, tmp_path, kind):
    if kind == "zsnet":
        dm = NYUScenesDataModule(str(nyu), cache_dir=str(tmp_path / "cache"), batch_size=2)
        module = ZSNetModule(ZSNet(width=8), num_lines=16, num_candidates=16)
    else:
        dm = NYULinesDataModule(str(nyu), cache_dir=str(tmp_path / "cache"), batch_size=2)
        module = LineEvidenceModule(LineEvidenceNet(width=8, context=4))
    # the splits of the fake set: scenes 0-3 all fall in the training range, so validation reads none
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 3 and len(dm.datasets["val"]) == 0
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0)
    trainer.fit(module, dm)


def test_renders_join_the_real_scenes_in_training_only(nyu, tmp_path):
    dm = NYULinesDataModule(str(nyu), renders=2, cache_dir=str(tmp_path / "cache"), batch_size=2,
                            render={"foliage": 0.8})
    dm.setup("fit")
    train = dm.datasets["train"]
    assert len(train) == 3 + 2 and len(dm.datasets["val"]) == 0
    rendered = train[4]  # after the real scenes; labelled from the render's object map
    n = len(rendered.segments)
    assert n > 0 and rendered.features.shape == (n, len(FEATURE_NAMES)) and rendered.direction.shape == (n,)
    assert any((tmp_path / "cache").glob("lines-640x480-*"))  # the renders keep a cache of their own
