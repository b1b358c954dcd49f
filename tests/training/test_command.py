"""ngp-train: packaged configs by name, --help naming export and plot, --version, a fast_dev_run that makes only
what it reads, the cache's progress bar on terminals only, TensorBoard as an extra logger, plotted curves."""

import logging
from pathlib import Path

import cv2
import lightning as L
import pytest
from lightning.pytorch.loggers import CSVLogger

import ngp_kornia
from ngp_kornia.nets.zsnet import ZSNet
from ngp_kornia.training.command import config_path, main, packaged_configs
from ngp_kornia.training.datamodules import RenderedDataModule
from ngp_kornia.training.plots import metric_label, plot_curves, read_metrics
from ngp_kornia.training.scene_data import RenderedScenes
from ngp_kornia.training.zsnet_module import ZSNetModule

ROOT = Path(__file__).resolve().parents[2]


def test_configs_ship_in_the_package_and_resolve_by_name():
    expected = ["evidence", "evidence_nyu", "fsnet", "fsnet_photos", "upright", "upright_lines", "zsnet", "zsnet_nyu"]
    assert packaged_configs() == expected
    path = config_path("zsnet")
    assert path.is_file() and path.parent == Path(ngp_kornia.__file__).parent / "configs"
    assert config_path("fsnet.yaml").name == "fsnet.yaml"
    packaged = "packaged: " + ", ".join(expected)
    with pytest.raises(FileNotFoundError, match=packaged):
        config_path("zsnett")


def test_top_level_configs_folder_is_the_packaged_one():
    # one copy: configs/ in a source checkout is the package's folder, so configs/zsnet.yaml keeps working
    assert (ROOT / "configs").resolve() == (Path(ngp_kornia.__file__).parent / "configs").resolve()


def test_unknown_config_is_a_usage_error(capsys):
    assert main(["fit", "--config", "nonsense"]) == 2
    assert "packaged: evidence, evidence_nyu, fsnet, fsnet_photos, upright, upright_lines," in capsys.readouterr().err


def test_help_names_export_and_plot_and_version(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "ngp-train export CHECKPOINT OUT.pt" in out and "ngp-train plot LOGDIR" in out and "--config zsnet" in out
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"ngp-train {ngp_kornia.__version__}"


def test_fast_dev_run_of_the_packaged_config_makes_only_what_it_reads(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the config's cache and runs folders are relative
    logging.getLogger("lightning.pytorch").setLevel(logging.WARNING)
    args = ["fit", "--config", "zsnet", "--trainer.fast_dev_run=true", "--trainer.enable_progress_bar=false"]
    assert main([*args, "--data.size=[160, 120]", "--data.batch_size=4", "--data.num_workers=0"]) == 0
    # one batch of training and one of validation scenes, not the config's 8,000 + 500 (+ 500 test)
    cached = sorted(p.parent.name + "/" + p.stem for p in (tmp_path / "cache").rglob("*.npz"))
    assert len(cached) == 8
    assert {int(name.split("/")[1]) for name in cached} == {0, 1, 2, 3, 1_000_000, 1_000_001, 1_000_002, 1_000_003}


def test_cache_progress_bar_on_request_or_terminal_only(tmp_path, capsys, monkeypatch):
    scenes = RenderedScenes(range(2), (96, 64), cache_dir=tmp_path / "a")
    scenes.prepare()  # stderr is not a terminal here: no bar
    assert capsys.readouterr().err == ""
    RenderedScenes(range(2), (96, 64), cache_dir=tmp_path / "b").prepare(progress=True)
    err = capsys.readouterr().err
    assert "caching rendered-96x64" in err and "2/2" in err


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """Two short epochs of ZSNet logged by a CSVLogger and a TensorBoardLogger."""
    pytest.importorskip("tensorboard", reason="the [tensorboard] extra is not installed")
    from lightning.pytorch.loggers import TensorBoardLogger

    root = tmp_path_factory.mktemp("logs")
    data = RenderedDataModule(cache_dir=None, train_size=4, val_size=2, test_size=2, size=(160, 120), batch_size=2)
    loggers = [CSVLogger(str(root / "csv")), TensorBoardLogger(str(root / "tb"))]
    trainer = L.Trainer(
        max_epochs=2, accelerator="cpu", logger=loggers, log_every_n_steps=1, enable_progress_bar=False,
        enable_checkpointing=False, enable_model_summary=False, num_sanity_val_steps=0,
    )
    trainer.fit(ZSNetModule(ZSNet(width=8), num_lines=32, num_candidates=32), data)
    return root


def test_tensorboard_and_csv_logs_read_the_same(logged):
    csv_metrics, tb_metrics = read_metrics(logged / "csv"), read_metrics(logged / "tb")
    for name in ("train/loss", "val/loss", "val/zenith_error", "val/zenith_error_uniform"):
        assert [s for s, _ in csv_metrics[name]] == [s for s, _ in tb_metrics[name]]
        assert [v for _, v in csv_metrics[name]] == pytest.approx([v for _, v in tb_metrics[name]], rel=1e-6)
    assert len(csv_metrics["val/zenith_error"]) == 2  # once per epoch


def test_plot_command_writes_labelled_curves(logged, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the [plot] extra is not installed")
    out = tmp_path / "curves.png"
    assert main(["plot", str(logged / "csv"), "-o", str(out)]) == 0
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 200 and image.shape[1] > 400
    figure = plot_curves(read_metrics(logged / "tb"))
    labels = {(ax.get_title(), ax.get_xlabel(), ax.get_ylabel()) for ax in figure.axes}
    assert ("loss", "training step", "loss") in labels
    assert ("zenith error", "training step", "zenith error (degrees)") in labels
    zenith = next(ax for ax in figure.axes if ax.get_title() == "zenith error")
    assert {line.get_label() for line in zenith.get_lines()} == {"val/zenith_error", "val/zenith_error_uniform"}


def test_plot_of_an_empty_folder_is_one_line(tmp_path, capsys):
    assert main(["plot", str(tmp_path), "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no metrics.csv" in err


def test_metric_labels_name_the_units():
    assert metric_label("val/horizon_error_manhattan") == "horizon error (fraction of image height)"
    assert metric_label("val/loss_cls") == "loss"


def test_readme_tensorboard_command_configures_both_loggers(tmp_path, monkeypatch, capsys):
    readme = (ROOT / "README.md").read_text().replace("\\\n", " ")
    line = next(x for x in readme.splitlines() if "TensorBoardLogger" in x and x.startswith("ngp-train fit"))
    args = line.split("#")[0].split()[1:]
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main([*args, "--print_config"])
    assert exit_info.value.code in (0, None)
    printed = capsys.readouterr().out
    assert "lightning.pytorch.loggers.CSVLogger" in printed and "lightning.pytorch.loggers.TensorBoardLogger" in printed


def _checkpoint(path):
    """A small checkpoint as ngp-train fit writes it (a ZSNet, its settings, an epoch and hyper-parameters)."""
    import torch

    net = ZSNet(width=8)
    state = {f"net.{k}": v for k, v in net.state_dict().items()}
    hyper = {"lr": 0.001, "num_lines": 32}
    torch.save({"state_dict": state, "ngp_network": {"name": "ZSNet", "settings": net.settings()}, "epoch": 3,
                "hyper_parameters": hyper, "optimizer_states": [{"state": {}}]}, path)
    return path


def test_export_never_overwrites_its_checkpoint(tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "run.ckpt")
    before = ckpt.read_bytes()
    for target in (ckpt, tmp_path / "." / "run.ckpt"):  # the same file, however it is named
        for force in ([], ["--force"]):
            assert main(["export", str(ckpt), str(target), *force]) == 1
            err = capsys.readouterr().err
            assert err == f"ngp-train: error: {target} is the checkpoint being exported; write the weights to " \
                          "another file, e.g. net.pt\n"
    assert ckpt.read_bytes() == before


def test_export_refuses_an_existing_output_unless_forced(tmp_path, capsys):
    from ngp_kornia.nets.weights import load_network

    ckpt, out = _checkpoint(tmp_path / "run.ckpt"), tmp_path / "zsnet.pt"
    out.write_bytes(b"weights a user keeps")
    assert main(["export", str(ckpt), str(out)]) == 1
    assert capsys.readouterr().err == f"ngp-train: error: {out} exists; add --force to overwrite it, or choose " \
                                      "another name\n"
    assert out.read_bytes() == b"weights a user keeps"
    assert main(["export", str(ckpt), str(out), "--force"]) == 0
    assert capsys.readouterr().out.strip() == str(out) and load_network(out, "ZSNet").settings()["width"] == 8


def test_export_to_a_folder_is_one_line(tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "run.ckpt")
    (tmp_path / "weights").mkdir()
    assert main(["export", str(ckpt), str(tmp_path / "weights"), "--force"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"ngp-train: error: {tmp_path / 'weights'} is a folder; give")


def test_fit_with_a_missing_data_folder_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    data = ["--data", "ngp_kornia.training.datamodules.PanoramaDataModule", "--data.panorama_dir", "no_such_folder"]
    args = ["fit", "--config", "zsnet", *data, "--trainer.fast_dev_run=true", "--trainer.enable_progress_bar=false"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err == "ngp-train: error: image folder not found: no_such_folder\n"
