"""FSNet training: labels of Eq. 16-20 with known answers, the loss's masking, a Lightning fast_dev_run."""

import math

import lightning as L
import pytest
import torch

from ngp_kornia.geometry import horizon_from_zenith, intrinsics_matrix
from ngp_kornia.geometry.frames import FrameCandidates, select_frames
from ngp_kornia.metrics import frame_horizon_error
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.training.datamodules import RenderedDataModule
from ngp_kornia.training.fsnet_module import FSNetModule
from ngp_kornia.training.losses import frame_classification_loss, frame_labels
from ngp_kornia.training.scene_data import SceneBatch

H, W = 480, 640


def _level_camera(focal_px: float) -> tuple[torch.Tensor, torch.Tensor]:
    """True zenith (homogeneous pixels, at infinity straight down) and horizon of a level camera."""
    K = intrinsics_matrix(torch.tensor([focal_px]), torch.tensor([319.5, 239.5]))
    zenith = torch.tensor([[0.0, 1.0, 0.0]])
    return zenith, horizon_from_zenith(K, zenith)


def _pitched_frame(focal_px: float, deg: float) -> FrameCandidates:
    """A candidate with the true focal length whose up direction is pitched by ``deg`` (pseudo camera)."""
    f = focal_px / (max(H, W) / 2)
    a = math.radians(deg)
    zenith = torch.tensor([[[0.0, f * math.cos(a), math.sin(a)]]])
    return FrameCandidates(zenith, None, torch.tensor([[f]]), None, None, torch.ones(1, 1, dtype=torch.bool))


def test_true_frame_scores_one():
    z, h = _level_camera(500.0)
    s_vh, labels, valid = frame_labels(_pitched_frame(500.0, 0.0), z, h, H, W)
    assert float(s_vh) == pytest.approx(1.0, abs=1e-5) and labels.tolist() == [[1.0]] and valid.all()


def test_zenith_20_degrees_off_is_negative():
    # telephoto (1000 px): 20 degrees of pitch move the horizon by 364 px = 0.76 image heights
    z, h = _level_camera(1000.0)
    fr = _pitched_frame(1000.0, 20.0)
    assert float(frame_horizon_error(fr, h, H, W)) == pytest.approx(1000 * math.tan(math.radians(20)) / H, rel=1e-4)
    s_vh, labels, _ = frame_labels(fr, z, h, H, W)
    assert float(s_vh) < 0.2 and labels.tolist() == [[0.0]]


def test_labels_are_lenient_in_image_heights():
    # documented property of the height unit: at 500 px, 20 degrees (0.38 heights) is still positive;
    # a smaller horizon_scale makes the labels stricter
    z, h = _level_camera(500.0)
    fr = _pitched_frame(500.0, 20.0)
    assert frame_labels(fr, z, h, H, W)[1].tolist() == [[1.0]]
    assert frame_labels(fr, z, h, H, W, horizon_scale=0.25)[1].tolist() == [[0.0]]


def test_invalid_frames_are_not_labelled_nor_in_the_loss():
    z, h = _level_camera(500.0)
    fr = _pitched_frame(500.0, 0.0)
    fr.valid = torch.zeros(1, 1, dtype=torch.bool)
    s_vh, labels, valid = frame_labels(fr, z, h, H, W)
    assert labels.tolist() == [[0.0]] and not valid.any() and float(s_vh) == 0.0
    logits = torch.tensor([[8.0, -8.0, 100.0]])
    loss = frame_classification_loss(logits, torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([[True, True, False]]))
    assert float(loss) < 1e-3
    assert float(frame_classification_loss(logits, torch.zeros(1, 3), torch.zeros(1, 3, dtype=torch.bool))) == 0.0


def test_select_frames_gathers_every_field():
    g = torch.Generator().manual_seed(0)
    fr = FrameCandidates(
        torch.rand(2, 5, 3, generator=g),
        torch.rand(2, 5, 3, generator=g),
        torch.rand(2, 5, generator=g),
        torch.rand(2, 5, 3, 3, generator=g),
        torch.rand(2, 5, 3, 3, generator=g),
        torch.rand(2, 5, generator=g) > 0.5,
    )
    idx = torch.tensor([[4, 1], [0, 3]])
    out = select_frames(fr, idx)
    assert torch.equal(out.R[1, 1], fr.R[1, 3]) and torch.equal(out.valid[0], fr.valid[0, [4, 1]])


def _tiny_net() -> FSNet:
    return FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)


def _small_parser() -> dict:
    return {"num_zenith": 64, "num_horizontal": 64, "num_frames": 128, "num_horizontal_frames": 64}


def test_missing_images_raise_a_clear_error():
    module = FSNetModule(_tiny_net(), num_candidates=2, parser_config=_small_parser())
    batch = SceneBatch(
        torch.rand(1, 4, 2, 2) * 100,
        torch.ones(1, 4, dtype=torch.bool),
        torch.eye(3)[None],
        torch.eye(3)[None],
        torch.tensor([[0.0, 1.0, 0.0]]),
        torch.tensor([[0.0, 1.0, -50.0]]),
        torch.tensor([[120, 160]]),
    )
    with pytest.raises(ValueError, match="input_size"):
        module._step(batch, "train", 0)


@pytest.mark.slow
def test_fast_dev_run(tmp_path):
    dm = RenderedDataModule(
        cache_dir=str(tmp_path / "cache"),
        train_size=2,
        val_size=2,
        test_size=1,
        size=(160, 120),
        input_size=(64, 64),
        batch_size=2,
    )
    module = FSNetModule(_tiny_net(), num_candidates=4, num_random=2, parser_config=_small_parser())
    before = [p.detach().clone() for p in module.net.parameters()]
    trainer = L.Trainer(fast_dev_run=True, accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.fit(module, dm)
    assert any(not torch.equal(a, b) for a, b in zip(before, module.net.parameters(), strict=True))
    metrics = trainer.callback_metrics
    for name in ("train/loss", "val/loss", "val/accuracy", "val/horizon_error", "val/horizon_error_manhattan"):
        assert torch.isfinite(metrics[name]), name
    ckpt = tmp_path / "m.ckpt"
    trainer.save_checkpoint(ckpt)
    saved = torch.load(ckpt, weights_only=False)
    assert saved["ngp_network"] == {"name": "FSNet", "settings": module.net.settings()}
    assert not any(k.startswith("parser") for k in saved["state_dict"])


def test_init_weights_start_from_the_shipped_fsnet():
    from ngp_kornia.nets.weights import load_network, shipped_weights

    shipped = load_network(shipped_weights("fsnet"), "FSNet")
    module = FSNetModule(FSNet(variant="shared", input_size=128), init_weights="fsnet")
    for name, tensor in shipped.state_dict().items():
        assert torch.equal(module.net.state_dict()[name], tensor)
    fresh = FSNetModule(FSNet(variant="shared", input_size=128))
    assert not all(torch.equal(fresh.net.state_dict()[k], v) for k, v in shipped.state_dict().items())


def test_init_weights_of_other_settings_is_one_clear_error():
    from ngp_kornia.errors import ConfigError

    with pytest.raises(ConfigError, match="input_size"):
        FSNetModule(FSNet(variant="shared", input_size=64), init_weights="fsnet")


def test_evidence_masks_the_segments_the_parser_drops_at_run_time():
    from ngp_kornia.nets.weights import load_network, shipped_weights
    from ngp_kornia.pipeline.evidence import apply_evidence

    g = torch.Generator().manual_seed(0)
    start = torch.rand(1, 60, 1, 2, generator=g) * torch.tensor([W, H])
    length = torch.cat([torch.full((1, 30, 1, 1), 150.0), torch.full((1, 30, 1, 1), 4.0)], 1)
    angle = torch.rand(1, 60, 1, 1, generator=g) * math.pi
    segments = torch.cat([start, start + length * torch.cat([angle.cos(), angle.sin()], -1)], 2)
    mask = torch.ones(1, 60, dtype=torch.bool)
    mask[0, -1] = False
    z, h = _level_camera(500.0)
    batch = SceneBatch(segments, mask, torch.eye(3)[None], torch.eye(3)[None], z, h, torch.tensor([[H, W]]))
    plain = FSNetModule(_tiny_net(), num_candidates=2, parser_config=_small_parser())
    assert plain._kept(batch) is batch
    module = FSNetModule(_tiny_net(), num_candidates=2, parser_config=_small_parser(), evidence_weights="evidence")
    kept = module._kept(batch).mask
    net = load_network(shipped_weights("evidence"), "LineEvidenceNet")
    expected = apply_evidence(net, torch.zeros(1, 3, H, W), segments, mask)[1]
    assert torch.equal(kept, expected) and not (kept & ~mask).any() and 0 < int(kept.sum()) < int(mask.sum())
    assert not any(k.startswith("evidence") for k in module.state_dict())
