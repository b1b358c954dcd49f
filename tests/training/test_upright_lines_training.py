"""Training the line reader through ngp-train: the photos' segments (detected once, cached), their turns and mirror
images as np.rot90 and np.fliplr move the pixels, each reader's own loss, the validation figures of the mean logits,
a fast_dev_run, export, and the fit of the temperature and fusion weights written into the weights file."""

import cv2
import lightning as L
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ngp_kornia.data.photo_split import split_photos
from ngp_kornia.errors import ConfigError
from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.weights import load_network, save_network
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.upright_lines_data import (
    LineSample,
    PhotoSegments,
    TurnedViews,
    UprightLinesDataModule,
    collate_lines,
)
from ngp_kornia.training.upright_lines_fit import fit_line_reader, main
from ngp_kornia.training.upright_lines_module import UprightLinesModule, view_features


def _photos(root, count=24):
    """A folder of small photos with a few dark lines drawn on a light ground, landscape and portrait."""
    rng = np.random.default_rng(0)
    for i in range(count):
        sub = root / ("x" if i % 2 else "y")
        sub.mkdir(parents=True, exist_ok=True)
        h, w = (60, 80) if i % 3 else (80, 60)
        image = np.full((h, w, 3), 210, np.uint8)
        for _ in range(3):
            p, q = rng.integers(0, [w, h], size=(2, 2))
            cv2.line(image, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), (30, 30, 30), 2)
        cv2.imwrite(str(sub / f"{i}.png"), image)
    return root


def test_views_move_the_segments_as_np_rot90_and_fliplr_move_the_pixels():
    image = np.arange(7 * 10).reshape(7, 10)  # every pixel a different value
    seg = np.array([[[1, 2], [8, 5]], [[0, 0], [9, 6]]], np.float32)
    views = TurnedViews([LineSample(seg, np.array([7, 10]))], mirrors=True)
    assert len(views) == 8 and [v[2] for v in views.keys] == [False] * 4 + [True] * 4
    for index, (_, turn, mirrored) in enumerate(views.keys):
        view = views[index]
        seen = np.rot90(np.fliplr(image) if mirrored else image, turn)
        assert view.image_size.tolist() == list(seen.shape) and view.turn.tolist() == [turn]
        for (x, y), (tx, ty) in zip(seg.reshape(-1, 2), view.segments.reshape(-1, 2), strict=True):
            assert seen[int(ty), int(tx)] == image[int(y), int(x)]  # the same pixel of the scene


def test_turned_segments_are_those_detected_on_the_turned_photo(tmp_path):
    root = _photos(tmp_path / "photos", 1)
    name = "y/0.png"
    views = TurnedViews(PhotoSegments(root, [name]), mirrors=False)
    rgb = cv2.imread(str(root / name))
    for turn in range(4):
        turned = cv2.imwrite(str(tmp_path / "turned.png"), np.ascontiguousarray(np.rot90(rgb, turn)))
        assert turned
        found = PhotoSegments(tmp_path, ["turned.png"])[0].segments
        ours = views[turn].segments
        assert len(ours) > 0 and len(found) > 0
        for s in ours:  # each segment found again within two pixels (LSD is not exactly turn-invariant)
            gap = np.minimum(np.abs(found - s).max((1, 2)), np.abs(found[:, ::-1] - s).max((1, 2)))
            assert gap.min() < 2.0


def test_segments_are_cached_by_folder_and_settings(tmp_path):
    from ngp_kornia.pipeline.settings import SegmentSettings

    root = _photos(tmp_path / "photos", 3)
    names = split_photos(root, "train") + split_photos(root, "calibrate") + split_photos(root, "test")
    first = PhotoSegments(root, names, tmp_path / "cache")
    first.prepare()
    assert len(list(first.cache.glob("*.npz"))) == 3
    assert PhotoSegments(root, names, tmp_path / "cache").cache == first.cache
    assert PhotoSegments(root, names, tmp_path / "cache", SegmentSettings(min_length=20)).cache != first.cache
    assert np.array_equal(first[0].segments, first.compute(first.keys[0]).segments)


def test_a_folder_without_held_back_photos_is_refused(tmp_path):
    root = _photos(tmp_path / "photos", 2)
    assert not split_photos(root, "calibrate")  # two photos: none held back
    with pytest.raises(ConfigError, match="calibrate part"):
        UprightLinesDataModule(photos=str(root)).setup("fit")
    with pytest.raises(ConfigError, match="not found"):
        UprightLinesDataModule(photos=str(tmp_path / "none")).setup("fit")


def _batch(views=6, seed=0):
    gen = torch.Generator().manual_seed(seed)
    samples = [LineSample((torch.rand(5 + i, 2, 2, generator=gen) * 50).numpy(), np.array([40 + i, 60]),
                          np.array([i % 4])) for i in range(views)]  # fmt: skip
    return collate_lines(samples)


def test_each_reader_learns_from_its_own_loss_and_validation_reads_the_mean():
    torch.manual_seed(0)
    module = UprightLinesModule(UprightLinesNet(width=8, members=2))
    logged = {}
    module.log = lambda name, value, **kw: logged.__setitem__(name, float(value.detach()))
    batch = _batch()
    module._step(batch, "train", 0).backward()
    alone = F.cross_entropy(module.net.readers[0](view_features(batch), batch.mask), batch.turns)
    expected = torch.autograd.grad(alone, list(module.net.readers[0].parameters()))
    for got, want in zip(module.net.readers[0].parameters(), expected, strict=True):
        assert torch.allclose(got.grad, want, atol=1e-6)
    module._step(batch, "val", 0)
    with torch.no_grad():
        mean = module.net.logits(view_features(batch), batch.mask)
    assert logged["val/nll"] == pytest.approx(float(F.cross_entropy(mean, batch.turns)), rel=1e-5)
    assert logged["val/accuracy"] == pytest.approx(float((mean.argmax(-1) == batch.turns).float().mean()))


def test_features_are_each_views_own():
    batch = _batch(3)
    net = UprightLinesNet(width=4, members=1).eval()
    with torch.no_grad():
        read = net.logits(view_features(batch), batch.mask)
        for i in range(3):
            h, w = batch.image_size[i].tolist()
            own = net(batch.segments[i : i + 1], batch.mask[i : i + 1], h, w)
            assert torch.allclose(torch.log_softmax(read[i], -1), own[0], atol=1e-5)


def test_fast_dev_run_exports_and_the_fit_is_written_into_the_weights(tmp_path):
    root = _photos(tmp_path / "photos", 40)
    held = split_photos(root, "calibrate")
    assert held
    dm = UprightLinesDataModule(photos=str(root), cache_dir=str(tmp_path / "cache"), batch_size=8)
    module = UprightLinesModule(UprightLinesNet(width=8, members=2))
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        default_root_dir=str(tmp_path))  # fmt: skip
    before = [p.detach().clone() for p in module.net.parameters()]
    trainer.fit(module, datamodule=dm)
    assert all(not torch.equal(a, b) for a, b in zip(before, module.net.parameters(), strict=True) if a.dim() > 1)
    trainer.save_checkpoint(tmp_path / "last.ckpt")
    out = export_checkpoint(tmp_path / "last.ckpt", tmp_path / "lines.pt")
    net = load_network(out, "UprightLinesNet")
    assert net.settings() == {"width": 8, "members": 2}
    assert torch.equal(net.readers[1].head[2].weight, module.net.readers[1].head[2].weight)
    upright = save_network(UprightNet(size=16, width=4), tmp_path / "upright.pt", {"size": 16, "width": 4})
    fit = fit_line_reader(out, root, upright)
    fitted = load_network(out, "UprightLinesNet")
    assert fit["photos"] == len(held) and float(fitted.temperature) == pytest.approx(fit["temperature"])
    assert fitted.fusion.tolist() == pytest.approx(fit["fusion"])
    assert fit["fused_nll"] <= fit["fused_nll_unweighted"] + 1e-9  # (1, 1) is where the fit starts
    assert torch.equal(fitted.readers[0].point[0].weight, net.readers[0].point[0].weight)
    meta = torch.load(out, weights_only=True)["metadata"]
    assert "hyper_parameters" in meta and meta["fit"]["photos"] == len(held)


def test_fit_command_names_its_purpose_and_refuses_a_folder_without_held_back_photos(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "INTO the given weights file" in " ".join(capsys.readouterr().out.split())
    net = UprightLinesNet(width=4, members=1)
    weights = save_network(net, tmp_path / "lines.pt", net.settings())
    before = weights.read_bytes()
    assert main([str(weights), "--photos", str(_photos(tmp_path / "photos", 2))]) == 1
    err = capsys.readouterr().err
    assert err.startswith("upright_lines_fit: error:") and "calibrate part" in err and err.count("\n") == 1
    assert weights.read_bytes() == before
