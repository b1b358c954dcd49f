"""``ngp-train``: Lightning's CLI over the networks' LightningModules and the rendered-data DataModule.

Examples::

    ngp-train fit --config configs/zsnet.yaml                      # train ZSNet on rendered scenes
    ngp-train fit --config configs/zsnet.yaml --ckpt_path last.ckpt  # resume
    ngp-train export runs/zsnet/checkpoints/best.ckpt ngp_kornia/weights/zsnet.pt
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

try:  # optional dependencies of the package: training needs them, calibrate() does not
    import jsonargparse  # noqa: F401  (LightningCLI's parser; imported here for a clear message)
    from lightning.pytorch.cli import LightningCLI
except ImportError as err:
    raise ImportError(f"training needs Lightning and jsonargparse ({err}); pip install 'ngp-kornia[train]'") from err

from ngp_kornia.models.weights import save_network

__all__ = ["export_checkpoint", "main"]


def export_checkpoint(checkpoint: str | Path, out: str | Path) -> Path:
    """Turn a training checkpoint into a small weights file holding only the network and its settings."""
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=False)
    config = ckpt.get("hyper_parameters", {})
    net_spec = _network_spec(ckpt)
    module = net_spec["class"](**net_spec["settings"])
    state = {k.removeprefix("net."): v for k, v in ckpt["state_dict"].items() if k.startswith("net.")}
    module.load_state_dict(state)
    meta = {"checkpoint": str(checkpoint), "epoch": ckpt.get("epoch"), "hyper_parameters": _plain(config)}
    return save_network(module, out, net_spec["settings"], meta)


def _network_spec(ckpt: dict) -> dict:
    from ngp_kornia.models.weights import NETWORKS

    init = ckpt.get("ngp_network")
    if not init or init.get("name") not in NETWORKS:
        raise ValueError("checkpoint has no network description; was it written by ngp-train?")
    return {"class": NETWORKS[init["name"]], "settings": init["settings"]}


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
        print(export_checkpoint(args[1], args[2]))
        return 0
    LightningCLI(args=argv, save_config_kwargs={"overwrite": True})  # None: Lightning reads sys.argv itself
    return 0


if __name__ == "__main__":
    sys.exit(main())
