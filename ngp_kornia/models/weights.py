"""Saving and loading network weights: one small file per network, with the settings needed to rebuild it.

Shipped weights live in ``ngp_kornia/weights/`` inside the package; nothing is ever downloaded.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ngp_kornia.errors import WeightsError
from ngp_kornia.models.fsnet import FSNet
from ngp_kornia.models.zsnet import ZSNet

__all__ = ["NETWORKS", "WEIGHTS_DIR", "WeightsError", "load_network", "network_name", "save_network", "shipped_weights"]

FORMAT = "ngp-kornia-weights"
VERSION = 1
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
#: the networks a weights file may hold, by name
NETWORKS: dict[str, type[nn.Module]] = {"FSNet": FSNet, "ZSNet": ZSNet}


def save_network(net: nn.Module, path: str | Path, settings: dict, metadata: dict | None = None) -> Path:
    """Write a network's weights with the constructor ``settings`` that rebuild it.

    Args:
        net: a network of :data:`NETWORKS`.
        path: output file.
        settings: keyword arguments of the network's constructor.
        metadata: free-form notes (training command, data, date), kept in the file.
    """
    name = type(net).__name__
    if name not in NETWORKS:
        raise WeightsError(f"cannot save a {name}: known networks are {', '.join(NETWORKS)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    payload = {"format": FORMAT, "version": VERSION, "network": name, "settings": settings, "state_dict": state}
    payload["metadata"] = metadata or {}
    torch.save(payload, path)
    return path


def load_network(path: str | Path, network: str) -> nn.Module:
    """Rebuild a network from a weights file written by :func:`save_network`, in eval mode.

    Args:
        path: the weights file.
        network: the expected network name (e.g. ``"ZSNet"``).

    Raises:
        WeightsError: the file is missing, is not a weights file, holds another network, or its tensors do not fit.
    """
    path = Path(path)
    payload = _read(path)
    if payload.get("network") != network:
        raise WeightsError(f"{path} holds {payload.get('network')!r} weights, expected {network!r}")
    try:
        net = NETWORKS[network](**payload.get("settings", {}))
        net.load_state_dict(payload["state_dict"])
    except (TypeError, RuntimeError, KeyError) as err:
        raise WeightsError(f"{path} does not fit a {network}: {err}") from None
    return net.eval()


def network_name(path: str | Path) -> str:
    """The name of the network a weights file holds (``"ZSNet"`` or ``"FSNet"``).

    Raises:
        WeightsError: the file is missing, is not a weights file, or holds an unknown network.
    """
    name = _read(Path(path)).get("network")
    if name not in NETWORKS:
        raise WeightsError(f"{path} holds weights of an unknown network {name!r}; known: {', '.join(NETWORKS)}")
    return name


def _read(path: Path) -> dict:
    if not path.is_file():
        raise WeightsError(f"weights file not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise WeightsError(f"{path} is not a readable weights file ({type(err).__name__}: {err})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise WeightsError(f"{path} is not an ngp-kornia weights file (expected format {FORMAT!r})")
    return payload


def shipped_weights(name: str) -> Path:
    """Path of a weights file shipped in the package (``ngp_kornia/weights/<name>.pt``)."""
    return WEIGHTS_DIR / f"{name}.pt"
