"""No file the package reads can run code: planted pickles in weights files, training checkpoints and training
caches are refused (or, for a cache, recomputed) with one line, and the code in them never runs."""

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia import calibrate
from ngp_kornia.errors import CheckpointError, NGPError, WeightsError
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.weights import FORMAT, VERSION, load_network, save_network
from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.command import export_checkpoint
from ngp_kornia.training.command import main as train_main


class Planted:
    """Unpickling this creates the file ``marker``: proof that loading ran code from the file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def test_planted_pickle_in_a_weights_file_is_refused_without_running(tmp_path):
    marker, path = tmp_path / "ran", tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "version": VERSION, "network": "ZSNet", "payload": Planted(marker)}, path)
    with pytest.raises(WeightsError, match=r"refused: the weights file holds a Python object \(posix.mkdir\)"):
        calibrate(torch.rand(3, 64, 64), weights=str(path))
    assert not marker.exists()


def _checkpoint(tmp_path, **extra):
    net = ZSNet(width=8)
    state = {f"net.{k}": v for k, v in net.state_dict().items()}
    ckpt = {"state_dict": state, "ngp_network": {"name": "ZSNet", "settings": net.settings()}, "epoch": 0, **extra}
    path = tmp_path / "m.ckpt"
    torch.save(ckpt, path)
    return path


def test_planted_pickle_in_a_checkpoint_is_refused_without_running(tmp_path):
    marker = tmp_path / "ran"
    path = _checkpoint(tmp_path, hyper_parameters={"lr": 0.1, "trap": Planted(marker)})
    with pytest.raises(CheckpointError, match="refused: the checkpoint holds a Python object"):
        export_checkpoint(path, tmp_path / "out.pt")
    assert not marker.exists() and not (tmp_path / "out.pt").exists()


def test_a_clean_checkpoint_still_exports(tmp_path):
    path = _checkpoint(tmp_path, hyper_parameters={"lr": 0.1})
    net = load_network(export_checkpoint(path, tmp_path / "out.pt"), "ZSNet")
    assert net.settings()["width"] == 8


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p / "none.ckpt", "checkpoint not found"),
        (lambda p: (p / "r.ckpt").write_bytes(np.random.default_rng(0).bytes(4096)) and p / "r.ckpt",
         "is not a readable checkpoint"),  # fmt: skip
        (lambda p: (p / "p.ckpt").write_bytes(b"\x80\x09" + bytes(64)) and p / "p.ckpt", "not a readable checkpoint"),
        (lambda p: torch.save({"epoch": 1}, p / "x.ckpt") or p / "x.ckpt", "has no network description"),
    ],
)
def test_ngp_train_export_errors_are_one_line(tmp_path, capsys, make, message):
    assert train_main(["export", str(make(tmp_path)), str(tmp_path / "out.pt")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ngp-train: error: ") and message in err and err.count("\n") == 1
    assert "weights_only" not in err and "Traceback" not in err


@pytest.mark.parametrize(
    "head",
    [b"", b"\x80\x09", b"PK\x03\x04"],  # random bytes; a pickle of an unknown protocol (torch warns); a zip's magic
    ids=["random", "pickle-protocol-9", "zip-magic"],
)
def test_random_bytes_as_weights_are_one_line_without_torch_advice(tmp_path, head):
    path, image = tmp_path / "random.pt", tmp_path / "image.png"
    path.write_bytes(head + np.random.default_rng(0).bytes(4096))
    cv2.imwrite(str(image), np.full((64, 64, 3), 128, np.uint8))
    run = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", "--weights", str(path), str(image)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    # a usage error (exit 2): argparse's usage line, then one error line naming the file
    *usage, error = run.stderr.splitlines()
    assert run.returncode == 2 and usage[0].startswith("usage: ngp calibrate")
    assert error.startswith(f"ngp calibrate: error: --weights: {path} is not a readable weights file")
    assert "weights_only" not in run.stderr and "Traceback" not in run.stderr


def _weights(tmp_path, net, settings=None, name="w.pt", tamper=None):
    path = tmp_path / name
    save_network(net, path, settings or net.settings())
    if tamper is not None:
        payload = torch.load(path, weights_only=True)
        tamper(payload)
        torch.save(payload, path)
    return path


def test_weights_full_of_nan_are_refused(tmp_path):
    def poison(payload):
        for value in payload["state_dict"].values():
            if value.is_floating_point():
                value.fill_(float("nan"))

    path = _weights(tmp_path, ZSNet(width=8), tamper=poison)
    with pytest.raises(WeightsError, match="NaN or infinite"):
        calibrate(torch.rand(3, 64, 64), weights=str(path))


def test_weights_claiming_a_huge_network_are_refused_before_allocating(tmp_path):
    def grow(payload):
        payload["settings"]["width"] = 10**5  # 40 GB of weights; the file holds those of width 8

    path = _weights(tmp_path, ZSNet(width=8), tamper=grow)
    import resource

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(WeightsError, match="do not build a ZSNet|does not fit a ZSNet with settings"):
        load_network(path, "ZSNet")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # kilobytes: nothing like 12 GB


def test_two_zsnet_files_are_an_error(tmp_path):
    a = _weights(tmp_path, ZSNet(width=8), name="a.pt")
    b = _weights(tmp_path, ZSNet(width=8), name="b.pt")
    with pytest.raises(WeightsError, match="two ZSNet weights files given"):
        calibrate(torch.rand(3, 64, 64), weights=[str(a), str(b)])
    fs = _weights(tmp_path, FSNet(), name="f.pt")
    assert calibrate(torch.rand(3, 64, 64), weights=[str(a), str(fs)]).focal.isfinite()


def test_errors_are_ngp_errors():
    assert issubclass(WeightsError, NGPError) and issubclass(CheckpointError, ValueError)


def test_planted_pickle_in_a_training_cache_is_recomputed_without_running(tmp_path):
    from ngp_kornia.training.scene_data import RenderedScenes

    scenes = RenderedScenes([0], cache_dir=tmp_path, size=(160, 120))
    good = scenes[0]
    path = scenes.cache / "0.npz"
    marker = tmp_path / "ran"
    np.savez(path, segments=np.array([Planted(marker)], dtype=object))
    again = scenes[0]
    assert not marker.exists() and np.array_equal(again.segments, good.segments)
    path.write_bytes(path.read_bytes()[:100])  # a truncated cache file, as a killed writer could leave
    assert np.array_equal(scenes[0].segments, good.segments)


def _inflating(source, target, inflated_bytes):
    """A copy of the torch file ``source`` whose first tensor storage is deflated data of ``inflated_bytes`` zeros
    (a zip bomb: a small file that torch would inflate into one buffer of the declared size)."""
    import zipfile

    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w") as bomb:
        storage = next(n for n in original.namelist() if n.split("/")[-2:-1] == ["data"])
        for name in original.namelist():
            if name != storage:
                bomb.writestr(original.getinfo(name), original.read(name))
                continue
            zeros = bytes(1 << 20)
            info = zipfile.ZipInfo(name)
            info.compress_type = zipfile.ZIP_DEFLATED
            with bomb.open(info, "w", force_zip64=True) as entry:
                for _ in range(inflated_bytes >> 20):
                    entry.write(zeros)
    return target


def test_a_weights_zip_that_would_inflate_to_gigabytes_is_refused_before_loading(tmp_path, monkeypatch):
    source = _weights(tmp_path, ZSNet(width=8))
    path = _inflating(source, tmp_path / "bomb.pt", 256 << 20)
    assert path.stat().st_size < 2 << 20  # a file of about a megabyte, 256 MB once inflated

    def never(*args, **kwargs):
        raise AssertionError("torch.load was called")

    monkeypatch.setattr(torch, "load", never)
    with pytest.raises(WeightsError, match=r"bomb.pt: refused: the weights file is .* would inflate to 0.2\d GB"):
        load_network(path, "ZSNet")
