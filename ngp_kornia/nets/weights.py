"""Saving and loading network weights: one small file per network, with the settings needed to rebuild it.

Shipped weights live in ``ngp_kornia/weights/`` inside the package; nothing is ever downloaded.
"""

from __future__ import annotations

import pickle
import re
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from ngp_kornia.errors import WeightsError
from ngp_kornia.io.files import open_file
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.zsnet import ZSNet

__all__ = [
    "MAX_INFLATION",
    "NETWORKS",
    "WEIGHTS_DIR",
    "WeightsError",
    "build_network",
    "load_network",
    "load_tensors_safely",
    "network_name",
    "save_network",
    "shipped_weights",
]

FORMAT = "ngp-kornia-weights"
VERSION = 1
#: how many times its own size a torch file's entries may inflate to: torch.save stores them uncompressed (about
#: 1x), and floats deflate by little; far more is a zip bomb, refused before torch.load inflates it
MAX_INFLATION = 16
WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
#: the networks a weights file may hold, by name
NETWORKS: dict[str, type[nn.Module]] = {
    "FSNet": FSNet, "LineEvidenceNet": LineEvidenceNet, "UprightNet": UprightNet, "UprightLinesNet": UprightLinesNet,
    "ZSNet": ZSNet,
}


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
    return build_network(network, payload.get("settings", {}), payload.get("state_dict"), path)


def build_network(network: str, settings: dict, state: dict, path: str | Path = "weights") -> nn.Module:
    """A network of :data:`NETWORKS` from its constructor settings and state_dict, checked before it is built.

    The tensors must be finite, and their shapes must be those the settings imply, which are worked out on the
    meta device first: settings claiming a huge network are refused without allocating it.

    Raises:
        WeightsError: settings that do not build the network, missing or extra tensors, other shapes, NaN.
    """
    if not isinstance(settings, dict) or not isinstance(state, dict):
        raise WeightsError(f"{path} lacks the settings or the state_dict of a {network}; re-export it with ngp-train")
    _check_tensors(path, state)
    try:  # the shapes the settings imply, on the meta device: nothing is allocated, whatever the settings claim
        with torch.device("meta"):
            skeleton = NETWORKS[network](**settings)
    except Exception as err:
        raise WeightsError(f"{path}: settings {settings} do not build a {network} ({_first_line(err)})") from None
    expected = {k: tuple(v.shape) for k, v in skeleton.state_dict().items()}
    found = {k: tuple(v.shape) for k, v in state.items()}
    if expected != found:
        key = next(k for k in sorted(expected.keys() | found.keys()) if expected.get(k) != found.get(k))
        in_file = list(found[key]) if key in found else "missing"
        in_net = list(expected[key]) if key in expected else "not a parameter"
        raise WeightsError(
            f"{path} does not fit a {network} with settings {settings}: {key!r} is {in_file} in the file, "
            f"{in_net} in the network"
        )
    net = NETWORKS[network](**settings)
    net.load_state_dict(state)
    return net.eval()


def _check_tensors(path: str | Path, state: dict) -> None:
    for key, value in state.items():
        if not isinstance(value, torch.Tensor):
            raise WeightsError(f"{path}: state_dict entry {key!r} is a {type(value).__name__}, not a tensor")
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise WeightsError(f"{path}: {key!r} holds NaN or infinite values; the training diverged, use another file")


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
    payload = load_tensors_safely(path, WeightsError, "weights file")
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise WeightsError(f"{path} is not an ngp-kornia weights file (expected format {FORMAT!r})")
    return payload


def load_tensors_safely(path: Path, error: type[Exception], what: str, allowed: Sequence = ()) -> object:
    """``torch.load`` that never runs code from the file: tensors and plain Python values only (``weights_only``),
    plus the ``allowed`` classes; every failure becomes one line of ``error``.

    The path must be a regular file (a directory, a FIFO or a looping link is named as such), and the sizes its zip
    entries declare must stay within :data:`MAX_INFLATION` times the file's size (plus 1 MiB): a small file that
    would inflate to gigabytes is refused before anything is inflated.

    Raises:
        error: the path is no readable file, the file is not a torch file, is damaged, would inflate too far, or
            holds objects that loading would have to run.
    """
    file, size = open_file(path, error, what)
    with file:
        _check_inflation(file, size, path, error, what)
        file.seek(0)
        return _load(file, path, error, what, allowed)


def _check_inflation(file, size: int, path: Path, error: type[Exception], what: str) -> None:
    """Refuse a zip whose entries declare more bytes than :data:`MAX_INFLATION` times the file's size.

    torch reads an entry into a buffer of its declared size and fails if it inflates further, so the declared sizes
    bound the memory that loading takes.
    """
    if not zipfile.is_zipfile(file):
        return  # torch's legacy format, a plain pickle: nothing in it is inflated
    try:
        file.seek(0)
        with zipfile.ZipFile(file) as archive:
            declared = sum(entry.file_size for entry in archive.infolist())
    except (zipfile.BadZipFile, OSError, ValueError) as err:
        raise error(f"{path} is not a readable {what} (a damaged zip archive: {err})") from None
    if declared > MAX_INFLATION * size + (1 << 20):
        raise error(
            f"{path}: refused: the {what} is {size / 1e6:.1f} MB but its entries would inflate to "
            f"{declared / 1e9:.2f} GB, more than {MAX_INFLATION} times its size; torch.save never writes such a file"
        )


def _load(file, path: Path, error: type[Exception], what: str, allowed: Sequence) -> object:
    try:  # torch warns of an unusual pickle protocol before failing on it: the failure below says it in one line
        with torch.serialization.safe_globals(list(allowed)), warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return torch.load(file, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"unsupported global:? (?:GLOBAL )?([\w.]+)", str(err), re.IGNORECASE)
        if found:
            raise error(
                f"{path}: refused: the {what} holds a Python object ({found.group(1)}) that loading would have to run; "
                f"only tensors and plain values are read"
            ) from None
        raise error(f"{path} is not a readable {what} ({_first_line(err)})") from None
    except Exception as err:  # torch raises many types for a damaged file
        raise error(f"{path} is not a readable {what} ({type(err).__name__}: {_first_line(err)})") from None


def _first_line(err: Exception) -> str:
    """The informative line of torch's message (its weights_only errors start with advice, not with the cause)."""
    text = str(err)
    if "WeightsUnpickler error:" in text:
        text = text.split("WeightsUnpickler error:", 1)[1]
    elif text.startswith("Weights only load failed"):
        text = text.split("\n", 1)[1] if "\n" in text else ""
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.startswith("Check the doc")]
    return lines[0] if lines else "the file ends too early" if isinstance(err, EOFError) else type(err).__name__


def shipped_weights(name: str) -> Path:
    """Path of a weights file shipped in the package (``ngp_kornia/weights/<name>.pt``)."""
    return WEIGHTS_DIR / f"{name}.pt"
