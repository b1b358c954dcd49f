"""``ngp-train``: Lightning's CLI over the networks' LightningModules and the rendered-data DataModule, plus
``export`` (a checkpoint to a weights file) and ``plot`` (the logged curves to a PNG).

Examples::

    ngp-train fit --config zsnet                                   # a packaged config by name: ZSNet on rendered scenes
    ngp-train fit --config zsnet --trainer.fast_dev_run=true       # one batch of each: checks the set-up in seconds
    ngp-train fit --config my.yaml --ckpt_path last.ckpt           # a config file of your own; resume
    ngp-train export runs/zsnet/lightning_logs/version_0/checkpoints/best.ckpt zsnet.pt
    ngp-train plot runs/zsnet -o curves.png                        # needs the [plot] extra

The module imports nothing heavy: :func:`parse` answers ``--help``, ``--version`` and wrong arguments (a missing
extra, checkpoint or config, an output that exists) before torch or Lightning is loaded; :func:`run` imports them.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from importlib import resources
from pathlib import Path

from ngp_kornia.errors import CheckpointError, NGPError, OutputError
from ngp_kornia.preflight import check_extra

__all__ = [
    "LIGHTNING_COMMANDS",
    "check_export",
    "config_path",
    "export_checkpoint",
    "main",
    "modules",
    "packaged_configs",
    "parse",
    "read_checkpoint",
    "run",
]

#: the commands LightningCLI runs (every other argument list is parsed here)
LIGHTNING_COMMANDS = ("fit", "validate", "test", "predict")
#: the options ngp-train answers itself (any other first option is LightningCLI's, e.g. --config, --print_config)
_OWN = ("-h", "--help", "--version")

_DESCRIPTION = (
    "Train ZSNet, FSNet, the line-evidence network, the orientation check and its line reader with Lightning (fit, "
    "validate, test, predict), then export the network (export) and plot its curves (plot)."
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


def check_export(checkpoint: str | Path, out: str | Path, force: bool = False) -> None:
    """Refuse an export that cannot run or would overwrite what it should not: a missing checkpoint, an output that
    is the checkpoint itself (even with ``force``), a folder, or a file that exists (unless ``force``).

    Raises:
        CheckpointError: no such checkpoint file.
        OutputError: the output is the checkpoint, a folder, or exists; the message names the fix.
    """
    checkpoint, out = Path(checkpoint), Path(out)
    if not checkpoint.is_file():
        raise CheckpointError(f"checkpoint not found: {checkpoint}")
    if out.exists() and out.resolve() == checkpoint.resolve():
        raise OutputError(f"{out} is the checkpoint being exported; write the weights to another file, e.g. net.pt")
    if out.is_dir():
        raise OutputError(f"{out} is a folder; give the weights file to write, e.g. {out / 'net.pt'}")
    if out.exists() and not force:
        raise OutputError(f"{out} exists; add --force to overwrite it, or choose another name")


def export_checkpoint(checkpoint: str | Path, out: str | Path, force: bool = False) -> Path:
    """Turn a training checkpoint into a small weights file holding only the network and its settings.

    The checkpoint is read without running code from it: tensors and plain values only (``weights_only``), so a
    checkpoint from an untrusted source cannot execute anything.

    Args:
        checkpoint: the Lightning checkpoint (``.ckpt``) written by ``ngp-train fit``.
        out: the weights file to write; never the checkpoint, and an existing file only with ``force``.
        force: overwrite ``out`` if it exists.

    Raises:
        CheckpointError: a missing or unreadable checkpoint, one that holds Python objects, or one not written by
            ``ngp-train``.
        OutputError: ``out`` is the checkpoint, a folder, or a file that exists (without ``force``).
        WeightsError: the network's tensors do not fit its settings or are not finite.
    """
    from ngp_kornia.nets.weights import build_network, save_network

    check_export(checkpoint, out, force)
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
    from ngp_kornia.nets.weights import load_tensors_safely

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
    from ngp_kornia.nets.weights import NETWORKS

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


class _Formatter(argparse.HelpFormatter):
    """argparse's help, wrapped only at spaces: a command such as ``ngp-train export`` is never cut at its hyphen."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent, subsequent_indent=indent,
                             break_on_hyphens=False)  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    """``ngp-train``'s own commands and help; the Lightning commands' options are LightningCLI's."""
    epilog = _EPILOG.format(names=", ".join(packaged_configs()))
    parser = argparse.ArgumentParser(prog="ngp-train", description=_DESCRIPTION, epilog=epilog,
                                     formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"ngp-train {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in LIGHTNING_COMMANDS:  # listed here, parsed by LightningCLI
        sub.add_parser(name, help=f"Lightning's {name}; ngp-train {name} --help lists its options")
    export = sub.add_parser(
        "export", help="write a trained network's weights file", description="Write the network of a training "
        "checkpoint as a weights file for calibrate(image, weights=OUT.pt) (ngp-train export CHECKPOINT OUT.pt).",
    )
    export.add_argument("checkpoint", help="the .ckpt file ngp-train fit wrote")
    export.add_argument("out", help="the weights file to write (.pt)")
    export.add_argument("--force", action="store_true", help="overwrite OUT if it exists (never the checkpoint)")
    plot = sub.add_parser(
        "plot", help="plot the logged curves (needs the [plot] extra)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Plot the loss and validation curves a CSVLogger or TensorBoardLogger wrote, against the step.",
    )
    plot.add_argument("logdir", help="the logger's folder (its newest metrics.csv or event file), or that file")
    plot.add_argument("-o", "--output", default="curves.png", help="the image to write (PNG)")
    return parser


def _version() -> str:
    from ngp_kornia import __version__

    return __version__


def parse(argv: list[str] | None = None) -> argparse.Namespace | int:
    """The command line, checked without importing torch or Lightning.

    ``--help``, ``--version`` and usage errors end here as argparse ends them (SystemExit); a missing extra,
    checkpoint or config, or an export that would overwrite a file, is one ``ngp-train: error:`` line and its exit
    status is returned. A Lightning command's arguments (``fit``, ... or options before one) are LightningCLI's,
    with packaged configs given by name resolved to their files.

    Returns:
        the arguments for :func:`run` (``lightning_args`` for a Lightning command), or the exit status.
    """
    from_command_line, argv = argv is None, list(sys.argv[1:] if argv is None else argv)
    lightning = bool(argv) and (argv[0] in LIGHTNING_COMMANDS or argv[0].startswith("-") and argv[0] not in _OWN)
    try:
        if lightning:
            check_extra(["lightning", "jsonargparse"], "training", "train")
            resolved = _resolve_configs(argv)
            return argparse.Namespace(command="lightning", lightning_args=resolved, from_command_line=from_command_line)
        args = _parser().parse_args(argv)
        if args.command == "export":
            check_extra(["lightning"], "ngp-train export", "train")  # Lightning's checkpoint classes
            check_export(args.checkpoint, args.out, args.force)
        elif args.command == "plot":
            check_extra(["matplotlib"], "ngp-train plot", "plot")
    except FileNotFoundError as err:  # a --config that is neither a file nor a packaged config
        print(f"ngp-train: error: {err}", file=sys.stderr)
        return 2
    except (ImportError, NGPError) as err:
        print(f"ngp-train: error: {err}", file=sys.stderr)
        return 1
    return args


def modules(args: argparse.Namespace) -> list[str]:
    """The heavy modules :func:`run` imports for these arguments (imported first by the ``ngp-train`` entry point)."""
    return {"export": ["ngp_kornia.nets.weights"], "plot": ["ngp_kornia.training.plots"]}.get(
        args.command, ["lightning.pytorch.cli"]
    )


def run(args: argparse.Namespace) -> int:
    """Run the command of :func:`parse`'s arguments; its exit status."""
    try:
        if args.command == "export":
            print(export_checkpoint(args.checkpoint, args.out, args.force))
        elif args.command == "plot":
            from ngp_kornia.training.plots import plot_curves, read_metrics

            plot_curves(read_metrics(args.logdir), args.output, title=str(args.logdir))
            print(args.output)
        else:
            _lightning(args.lightning_args, args.from_command_line)
    except (NGPError, OSError, ValueError, ImportError) as err:  # a missing data folder, a bad log folder, ...
        print(f"ngp-train{' plot' if args.command == 'plot' else ''}: error: {_one_line(err)}", file=sys.stderr)
        return 1
    return 0


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


def _lightning(args: list[str] | None, from_command_line: bool) -> None:
    from lightning.pytorch.cli import LightningCLI

    if from_command_line:  # Lightning reads sys.argv itself (and warns when given both)
        sys.argv[1:], args = args, None
    epilog = _EPILOG.format(names=", ".join(packaged_configs()))
    parser_kwargs = {"description": _DESCRIPTION, "epilog": epilog}
    LightningCLI(args=args, save_config_kwargs={"overwrite": True}, parser_kwargs=parser_kwargs)
    _close_process_group()  # not after an error: a peer may never reach the barrier


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ngp-train`` command: :func:`parse`, then :func:`run`."""
    args = parse(argv)
    return args if isinstance(args, int) else run(args)


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
