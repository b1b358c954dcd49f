"""``ngp-train``: Lightning's CLI over the networks' LightningModules and the rendered-data DataModule, plus
``export`` (a checkpoint to a weights file) and ``plot`` (the logged curves to a PNG).

Examples::

    ngp-train fit --config zsnet                                   # a packaged config by name: ZSNet on rendered scenes
    ngp-train fit --config zsnet --trainer.fast_dev_run=true       # one batch of each: checks the set-up in seconds
    ngp-train fit --config my.yaml --ckpt_path last.ckpt           # a config file of your own; resume
    ngp-train export runs/zsnet/lightning_logs/version_0/checkpoints/best.ckpt zsnet.pt
    ngp-train plot runs/zsnet -o curves.png                        # needs the [plot] extra
"""

from __future__ import annotations

import sys
from importlib import resources
from pathlib import Path

try:  # optional dependencies of the package: training needs them, calibrate() does not
    import jsonargparse  # noqa: F401  (LightningCLI's parser; imported here for a clear message)
    from lightning.pytorch.cli import LightningCLI
except ImportError as err:
    raise ImportError(f"training needs Lightning and jsonargparse ({err}); pip install 'ngp-kornia[train]'") from err

from ngp_kornia.errors import CheckpointError, NGPError
from ngp_kornia.models.weights import NETWORKS, build_network, load_tensors_safely, save_network

__all__ = ["config_path", "export_checkpoint", "main", "packaged_configs", "read_checkpoint"]

_DESCRIPTION = (
    "Train ZSNet, FSNet and the line-evidence network with Lightning (fit, validate, test, predict), then export the "
    "network (export) and plot its curves (plot)."
)
_EPILOG = (
    "Packaged configs, by name: {names} (e.g. --config zsnet; a path to a YAML file of your own works too). "
    "Two more commands: 'ngp-train export CHECKPOINT OUT.pt' writes a trained network's weights file for "
    "calibrate(image, weights=OUT.pt); 'ngp-train plot LOGDIR -o curves.png' plots the logged loss and validation "
    "curves (needs the [plot] extra)."
)


def packaged_configs() -> list[str]:
    """Names of the training configs shipped in ``ngp_kornia/configs`` (``--config NAME``)."""
    folder = resources.files("ngp_kornia") / "configs"
    return sorted(p.name.removesuffix(".yaml") for p in folder.iterdir() if p.name.endswith(".yaml"))


def config_path(name: str | Path) -> Path:
    """The file of a ``--config`` value: an existing file as it is, else the packaged config of that name.

    Raises:
        FileNotFoundError: neither; the message lists the packaged names.
    """
    if Path(name).is_file():
        return Path(name)
    packaged = Path(str(resources.files("ngp_kornia") / "configs" / f"{Path(name).name.removesuffix('.yaml')}.yaml"))
    if packaged.is_file() and Path(name).name in (packaged.name, packaged.stem) and Path(name).parent == Path("."):
        return packaged
    raise FileNotFoundError(
        f"--config {name}: no such file, and no packaged config of that name "
        f"(packaged: {', '.join(packaged_configs())})"
    )


def _resolve_configs(args: list[str]) -> list[str]:
    """``--config NAME`` / ``-c NAME`` / ``--config=NAME`` with NAME a packaged config -> its path."""
    out = list(args)
    for i, arg in enumerate(out):
        if arg in ("--config", "-c") and i + 1 < len(out):
            out[i + 1] = str(config_path(out[i + 1]))
        elif arg.startswith("--config="):
            out[i] = f"--config={config_path(arg.split('=', 1)[1])}"
    return out


def export_checkpoint(checkpoint: str | Path, out: str | Path) -> Path:
    """Turn a training checkpoint into a small weights file holding only the network and its settings.

    The checkpoint is read without running code from it: tensors and plain values only (``weights_only``), so a
    checkpoint from an untrusted source cannot execute anything.

    Raises:
        CheckpointError: a missing or unreadable checkpoint, one that holds Python objects, or one not written by
            ``ngp-train``.
        WeightsError: the network's tensors do not fit its settings or are not finite.
    """
    ckpt = read_checkpoint(checkpoint)
    net_spec = _network_spec(ckpt, checkpoint)
    state = ckpt.get("state_dict")
    if not isinstance(state, dict):
        raise CheckpointError(f"{checkpoint}: no state_dict in the checkpoint; was it written by ngp-train fit?")
    state = {k.removeprefix("net."): v for k, v in state.items() if k.startswith("net.")}
    module = build_network(net_spec["name"], net_spec["settings"], state, checkpoint)  # checked as weights files are
    config = ckpt.get("hyper_parameters", {})
    meta = {"checkpoint": str(checkpoint), "epoch": ckpt.get("epoch"), "hyper_parameters": _plain(config)}
    return save_network(module, out, net_spec["settings"], meta)


def read_checkpoint(checkpoint: str | Path) -> dict:
    """A Lightning checkpoint as a dict, loaded with ``weights_only=True`` (nothing in the file is run).

    Raises:
        CheckpointError: missing, unreadable, not a dict, or holding Python objects.
    """
    path = Path(checkpoint)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    ckpt = load_tensors_safely(path, CheckpointError, "checkpoint", allowed=_checkpoint_globals())
    if not isinstance(ckpt, dict):
        raise CheckpointError(f"{path} is not a Lightning checkpoint (it holds a {type(ckpt).__name__}, not a dict)")
    return ckpt


def _checkpoint_globals() -> list:
    """Plain-data classes Lightning may write into a checkpoint's hyper-parameters (never code)."""
    from lightning.fabric.utilities.data import AttributeDict

    return [AttributeDict]


def _network_spec(ckpt: dict, checkpoint) -> dict:
    init = ckpt.get("ngp_network")
    if not isinstance(init, dict) or init.get("name") not in NETWORKS or not isinstance(init.get("settings"), dict):
        raise CheckpointError(f"{checkpoint}: the checkpoint has no network description; was it written by ngp-train?")
    return {"name": init["name"], "settings": init["settings"]}


def _plain(value):
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value if isinstance(value, (int, float, str, bool, type(None))) else str(value)


def _plot(args: list[str]) -> int:
    import argparse

    from ngp_kornia.training.plots import plot_curves, read_metrics

    parser = argparse.ArgumentParser(
        prog="ngp-train plot",
        description="Plot the loss and validation curves a CSVLogger or TensorBoardLogger wrote, against the step.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("logdir", help="the logger's folder (its newest metrics.csv or event file), or that file")
    parser.add_argument("-o", "--output", default="curves.png", help="the image to write (PNG)")
    opts = parser.parse_args(args)
    try:
        plot_curves(read_metrics(opts.logdir), opts.output, title=str(opts.logdir))
    except (OSError, ValueError, ImportError) as err:
        print(f"ngp-train plot: error: {err}", file=sys.stderr)
        return 1
    print(opts.output)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["--version"]:
        from ngp_kornia import __version__

        print(f"ngp-train {__version__}")
        return 0
    if args[:1] == ["export"]:
        if len(args) != 3:
            print("usage: ngp-train export CHECKPOINT OUT.pt", file=sys.stderr)
            return 2
        try:
            print(export_checkpoint(args[1], args[2]))
        except (NGPError, OSError) as err:
            print(f"ngp-train: error: {err}", file=sys.stderr)
            return 1
        return 0
    if args[:1] == ["plot"]:
        return _plot(args[1:])
    try:
        args = _resolve_configs(args)
    except FileNotFoundError as err:
        print(f"ngp-train: error: {err}", file=sys.stderr)
        return 2
    epilog = _EPILOG.format(names=", ".join(packaged_configs()))
    if argv is None:  # Lightning reads sys.argv itself (and warns when given both)
        sys.argv[1:], args = args, None
    parser_kwargs = {"description": _DESCRIPTION, "epilog": epilog}
    LightningCLI(args=args, save_config_kwargs={"overwrite": True}, parser_kwargs=parser_kwargs)
    _close_process_group()
    return 0


def _close_process_group() -> None:
    """Let every process of a multi-process run finish together and close gloo's connections before exit.

    Lightning leaves the process group open; when one process exits while a peer's gloo thread still holds the
    connection, the C++ runtime can abort that peer at interpreter shutdown (exit -6 after a finished run).
    """
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


if __name__ == "__main__":
    sys.exit(main())
