"""``ngp-train``: Lightning's CLI over the networks' LightningModules and the rendered-data DataModule.

Examples::

    ngp-train fit --config configs/zsnet.yaml                      # train ZSNet on rendered scenes
    ngp-train fit --config configs/zsnet.yaml --ckpt_path last.ckpt  # resume
    ngp-train export runs/zsnet/checkpoints/best.ckpt ngp_kornia/weights/zsnet.pt
"""

from __future__ import annotations

import sys
from pathlib import Path

from lightning.pytorch.cli import LightningCLI

from ngp_kornia.errors import CheckpointError, NGPError
from ngp_kornia.models.weights import NETWORKS, build_network, load_tensors_safely, save_network

__all__ = ["export_checkpoint", "main", "read_checkpoint"]


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


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
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
    LightningCLI(args=argv, save_config_kwargs={"overwrite": True})  # None: Lightning reads sys.argv itself
    return 0


if __name__ == "__main__":
    sys.exit(main())
