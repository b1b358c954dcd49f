"""On a CUDA device (``make test-gpu``; skipped without one): the parser's batch path gives each image what the CPU
gives it, and one training step of each LightningModule runs on the GPU and moves its network's weights."""

import lightning as L
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.datamodules import RenderedDataModule
from ngp_kornia.training.evidence_data import LineEvidenceDataModule
from ngp_kornia.training.evidence_module import LineEvidenceModule
from ngp_kornia.training.fsnet_module import FSNetModule
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.upright_data import UprightDataModule
from ngp_kornia.training.upright_lines_data import UprightLinesDataModule
from ngp_kornia.training.upright_lines_module import UprightLinesModule
from ngp_kornia.training.upright_module import UprightModule
from ngp_kornia.training.zsnet_module import ZSNetModule

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device"),
]


def _photos(count: int = 4) -> torch.Tensor:
    scenes = [render_scene(seed, (320, 240)) for seed in range(count)]
    return torch.stack([torch.from_numpy(s.image).permute(2, 0, 1) for s in scenes]).float() / 255


@pytest.mark.parametrize("weights", ["none", "default"])
def test_the_batch_path_on_cuda_gives_each_image_the_cpu_answer(weights):
    images = _photos()
    on_gpu = calibrate(images.cuda(), weights=weights, seed=0)
    on_cpu = calibrate(images, weights=weights, seed=0)
    for name in ("K", "R", "horizon", "zenith", "vps", "focal", "pitch", "roll", "score", "valid"):
        assert getattr(on_gpu, name).device.type == "cuda", name
    assert on_gpu.camera.params.device.type == "cuda"
    # the GPU's arithmetic rounds otherwise: the same answer to well under a pixel and a tenth of a degree
    agree = (on_gpu.horizon.cpu() - on_cpu.horizon).abs().amax(-1) < 0.5  # line offsets in pixels, unit normals
    assert int(agree.sum()) >= len(images) - 1, (on_gpu.horizon.cpu(), on_cpu.horizon)
    close = (on_gpu.pitch.cpu() - on_cpu.pitch).abs() < 0.1
    assert int(close.sum()) >= len(images) - 1
    alone = calibrate(images[1:2].cuda(), weights=weights, seed=0)
    torch.testing.assert_close(alone.horizon, on_gpu.horizon[1:2], atol=1e-3, rtol=1e-4)


def _one_step(module: L.LightningModule, datamodule: L.LightningDataModule, net: torch.nn.Module) -> None:
    before = [p.detach().clone() for p in net.parameters()]
    trainer = L.Trainer(fast_dev_run=1, accelerator="gpu", devices=1, logger=False, enable_progress_bar=False,
                        enable_model_summary=False)
    trainer.fit(module, datamodule=datamodule)
    assert next(net.parameters()).device.type == "cuda"
    moved = [not torch.equal(b, p.detach().cpu()) for b, p in zip(before, net.parameters(), strict=True)]
    assert any(moved), "the training step changed no weight"


def test_one_zsnet_training_step_on_cuda(tmp_path):
    net = ZSNet(width=8)
    datamodule = RenderedDataModule(cache_dir=str(tmp_path), train_size=2, val_size=2, test_size=2, size=(320, 240),
                                    batch_size=2)
    _one_step(ZSNetModule(net), datamodule, net)


def test_one_fsnet_training_step_on_cuda(tmp_path):
    net = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)
    datamodule = RenderedDataModule(cache_dir=str(tmp_path), train_size=2, val_size=2, test_size=1, size=(160, 120),
                                    input_size=(64, 64), batch_size=2)
    parser = {"num_zenith": 64, "num_horizontal": 64, "num_frames": 128, "num_horizontal_frames": 64}
    _one_step(FSNetModule(net, num_candidates=4, num_random=2, parser_config=parser), datamodule, net)


def test_one_line_evidence_training_step_on_cuda(tmp_path):
    net = LineEvidenceNet(width=8, context=4)
    datamodule = LineEvidenceDataModule(cache_dir=str(tmp_path), train_size=2, val_size=2, test_size=2,
                                        size=(320, 240), batch_size=2)
    _one_step(LineEvidenceModule(net), datamodule, net)


def test_one_upright_training_step_on_cuda(tmp_path):
    net = UprightNet(size=32, width=4)
    datamodule = UprightDataModule(cache_dir=str(tmp_path), train_size=4, val_size=4, test_size=4, batch_size=4,
                                   size=32, structureless_every=2)
    _one_step(UprightModule(net), datamodule, net)


def test_one_line_reader_training_step_on_cuda(tmp_path):
    import cv2
    import numpy as np

    for i in range(40):  # enough photos for a calibrate part (one in eight)
        image = np.full((60, 80, 3), 210, np.uint8)
        cv2.line(image, (5 + i, 5), (70, 50 - i // 2), (30, 30, 30), 2)
        cv2.imwrite(str(tmp_path / f"{i}.png"), image)
    net = UprightLinesNet(width=8, members=2)
    datamodule = UprightLinesDataModule(photos=str(tmp_path), cache_dir=str(tmp_path / "cache"), batch_size=8)
    _one_step(UprightLinesModule(net), datamodule, net)
