"""Labels for unlabelled photos: which answers count as sure, the CSV the command writes and reads back, the cut of a
photo to the renders' size with its camera, and FSNet training on photos mixed with renders."""

import math
from types import SimpleNamespace

import cv2
import lightning as L
import numpy as np
import pytest
import torch

from ngp_kornia.data.manifest import CSVManifest
from ngp_kornia.data.photo_split import photo_part
from ngp_kornia.geometry import (
    horizon_from_zenith,
    intrinsics_matrix,
    rotation_from_angles,
    up_from_rotation,
    zenith_from_up,
)
from ngp_kornia.pipeline.parser import NeuralGeometricParser
from ngp_kornia.training.pseudo_labels import LabelRule, label_photo, main, sure_label
from ngp_kornia.training.scene_data import fit_photo
from ngp_kornia.training.synth.render import render_scene

H, W = 480, 640


def _answer(y_left: float, y_right: float, confidence: float = 0.9, focal: float = 500.0, valid: bool = True):
    """A stand-in for a one-image Calibration: a horizon through (-0.5, y_left) and (W - 0.5, y_right)."""
    p, q = torch.tensor([-0.5, y_left, 1.0]), torch.tensor([W - 0.5, y_right, 1.0])
    return SimpleNamespace(horizon=torch.linalg.cross(p, q), valid=torch.tensor(valid), focal=torch.tensor(focal),
                           confidence=torch.tensor(confidence), pitch=torch.tensor(2.0), roll=torch.tensor(-1.0))


def test_answers_that_agree_give_the_first_ones_label():
    answers = [_answer(240, 250), _answer(241, 251), _answer(243, 249, focal=520.0), _answer(238, 250, 0.2)]
    label = sure_label(answers, H, W, LabelRule(seeds=(0, 1)))
    assert label["focal_px"] == 500.0 and label["pitch_deg"] == 2.0 and label["roll_deg"] == -1.0
    assert label["horizon_spread"] == pytest.approx(3 / H) and label["focal_spread"] == pytest.approx(0.04)
    assert label["confidence"] == pytest.approx(0.9)  # the second weight set's confidence is not asked


@pytest.mark.parametrize(
    "odd, why",
    [
        (_answer(248, 250), "horizon 8 px = 1.7% of the height away"),
        (_answer(240, 250, focal=600.0), "focal length 20% away"),
        (_answer(240, 250, valid=False), "no camera found"),
    ],
)
def test_one_run_that_disagrees_leaves_the_photo_unlabelled(odd, why):
    assert sure_label([_answer(240, 250), _answer(240, 250), odd], H, W, LabelRule(seeds=(0, 1))) is None, why


def test_an_unsure_first_weight_set_leaves_the_photo_unlabelled():
    answers = [_answer(240, 250), _answer(240, 250, confidence=0.45), _answer(240, 250)]
    assert sure_label(answers, H, W, LabelRule(seeds=(0, 1))) is None
    assert sure_label(answers, H, W, LabelRule(seeds=(0, 1), min_confidence=0.4)) is not None


def test_a_far_rolled_answer_is_no_label_however_sure():
    rolled = _answer(240, 250)
    rolled.roll = torch.tensor(-31.0)
    assert sure_label([rolled, _answer(240, 250)], H, W, LabelRule(seeds=(0, 1))) is None
    assert sure_label([rolled, _answer(240, 250)], H, W, LabelRule(seeds=(0, 1), max_roll=45.0)) is not None


def test_a_rule_out_of_range_is_refused():
    with pytest.raises(ValueError, match="max_horizon_spread"):
        LabelRule(max_horizon_spread=2.0)
    with pytest.raises(ValueError, match="at least one"):
        LabelRule(seeds=())


def test_fit_photo_keeps_every_scene_direction_where_the_cut_puts_it():
    # a direction seen by a camera lands on the cut and resized photo where the new intrinsics project it
    K = intrinsics_matrix(torch.tensor([700.0], dtype=torch.float64), torch.tensor([399.5, 299.5]).double())[0]
    R = rotation_from_angles(torch.tensor([8.0]).double(), torch.tensor([-3.0]).double())[0]
    for shape, size in (((600, 800, 3), (640, 480)), ((900, 600, 3), (640, 480)), ((601, 799, 3), (320, 240))):
        rgb = np.zeros(shape, np.uint8)
        image, K2 = fit_photo(rgb, K, size)
        assert image.shape == (size[1], size[0], 3)
        height, width = shape[:2]
        scale = min(width / size[0], height / size[1])
        x0, y0 = (width - round(size[0] * scale)) // 2, (height - round(size[1] * scale)) // 2
        for d in torch.tensor([[0.1, -0.2, 1.0], [-0.3, 0.1, 1.0]], dtype=torch.float64):
            p = K @ R @ d
            p2 = K2 @ R @ d
            sx = size[0] / round(size[0] * scale)
            expected = ((p[0] / p[2] - x0 + 0.5) * sx - 0.5, (p[1] / p[2] - y0 + 0.5) * sx - 0.5)
            assert (p2[0] / p2[2]).item() == pytest.approx(expected[0], abs=0.5)
            assert (p2[1] / p2[2]).item() == pytest.approx(expected[1], abs=0.5)


def _render_folder(root, count: int, part: str = "train") -> list:
    """Renders saved as photos of ``part`` of a folder (names chosen so the split puts them there); their scenes."""
    scenes, i = [], 0
    while len(scenes) < count:
        name = f"street_{i:03d}.png"
        i += 1
        if photo_part(name) != part:
            continue
        scene = render_scene(len(scenes) + 11, (320, 240))
        cv2.imwrite(str(root / name), cv2.cvtColor(scene.image, cv2.COLOR_RGB2BGR))
        scenes.append((name, scene))
    return scenes


@pytest.mark.slow
def test_command_labels_a_folder_and_the_manifest_reads_back(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    scenes = _render_folder(photos, 3)
    out = tmp_path / "labels.csv"
    lenient = ["--weights", "none", "--seeds", "0", "--min-confidence", "0", "--max-horizon-spread", "1"]
    assert main([str(photos), str(out), *lenient]) == 0
    assert capsys.readouterr().out.startswith("3 photos of 3 labelled")
    rows = CSVManifest(out, root=photos)
    parser = NeuralGeometricParser.from_pretrained("none")
    rule = LabelRule(("none",), (0,), 0.0, 1.0, 1.0)
    for row, (name, scene) in zip(rows, scenes, strict=True):
        label = label_photo([parser], photos / name, rule)
        assert row.image_path.name == name and row.focal == pytest.approx(label["focal_px"], rel=1e-4)
        assert row.pitch == pytest.approx(label["pitch_deg"], abs=1e-3)
        assert abs(row.pitch - float(scene.pitch)) < 5.0  # a sure answer on a clean render is near its truth
    assert main([str(photos), str(out), *lenient]) == 2  # an existing file is never overwritten unasked
    assert "exists" in capsys.readouterr().err


@pytest.mark.slow
def test_fsnet_trains_on_labelled_photos_mixed_with_renders(tmp_path):
    from ngp_kornia.nets.fsnet import FSNet
    from ngp_kornia.training.datamodules import PhotosAndRendersDataModule
    from ngp_kornia.training.fsnet_module import FSNetModule

    photos = tmp_path / "photos"
    photos.mkdir()
    scenes = _render_folder(photos, 2)
    lines = ["image,focal_px,pitch_deg,roll_deg"]
    lines += [f"{n},{float(s.focal):.3f},{float(s.pitch):.4f},{float(s.roll):.4f}" for n, s in scenes]
    (tmp_path / "labels.csv").write_text("\n".join(lines) + "\n")
    labels = str(tmp_path / "labels.csv")
    dm = PhotosAndRendersDataModule(labels, labels, str(photos), photo_repeat=2, val_size=1,
                                    cache_dir=str(tmp_path / "cache"), train_size=2, size=(160, 120),
                                    input_size=(64, 64), batch_size=2)  # fmt: skip
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 2 + 2 * 2 and len(dm.datasets["val"]) == 2 + 1
    sample = dm.datasets["val"][0]
    assert tuple(sample.image_size) == (120, 160) and sample.image.shape == (64, 64, 3)
    # the cut photo's horizon is the labelled camera's: its zenith from the new K and the labelled up direction
    K = torch.from_numpy(sample.K)
    pitch, roll = (torch.tensor([float(v)], dtype=torch.float64) for v in (scenes[0][1].pitch, scenes[0][1].roll))
    up = up_from_rotation(rotation_from_angles(pitch, roll))
    expected = horizon_from_zenith(K[None], zenith_from_up(K[None], up))[0]
    assert torch.allclose(torch.from_numpy(sample.horizon), expected, atol=1e-6)
    net = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)
    small = {"num_zenith": 64, "num_horizontal": 64, "num_frames": 128, "num_horizontal_frames": 64}
    module = FSNetModule(net, num_candidates=4, num_random=2, parser_config=small)
    trainer = L.Trainer(fast_dev_run=2, accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.fit(module, dm)
    assert all(math.isfinite(float(trainer.callback_metrics[k])) for k in ("train/loss", "val/horizon_auc"))
