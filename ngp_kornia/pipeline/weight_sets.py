"""The weight sets a parser is built from: the shipped networks by name (or weights files by path), and the settings
that come with them (``"default"`` turns the line evidence on).

:meth:`~ngp_kornia.pipeline.parser.NeuralGeometricParser.from_pretrained` and :func:`ngp_kornia.calibrate` take a
weight set as these functions check it; the networks are loaded once per process and shared read-only.
"""

from __future__ import annotations

from collections.abc import Mapping
from copy import deepcopy
from functools import lru_cache
from pathlib import Path

from torch import nn

from ngp_kornia.errors import ConfigError, WeightsError, shown
from ngp_kornia.nets.weights import load_network, network_name, shipped_weights
from ngp_kornia.pipeline.settings import ParserConfig

__all__ = [
    "DEFAULT_SETTINGS",
    "DEFAULT_WEIGHTS",
    "WEIGHTS",
    "check_weights",
    "checked_config",
    "network_roles",
    "weight_set_config",
]

#: weight sets by name; paths to weights files (``.pt``) work too.
WEIGHTS = ("default", "none", "zsnet", "fsnet", "full")
#: what "default" means: the networks of this weight set with :data:`DEFAULT_SETTINGS`, the configuration that beats
#: the geometric path on the real sets by the paired rule (BENCHMARKS.md, docs/lab-notes/real-scenes.md).
DEFAULT_WEIGHTS = "full"
#: the settings "default" changes (a ``config`` mapping changes them further; a whole ParserConfig replaces them):
#: the line evidence drops the segments it reads as clutter before the candidates are sampled
DEFAULT_SETTINGS = {"evidence.enabled": True}
#: the shipped networks each named weight set uses
_NAMED = {"none": (), "zsnet": ("zsnet",), "fsnet": ("fsnet",), "full": ("zsnet", "fsnet")}
#: the networks every weight set has (the line evidence, the orientation and structure check), by shipped file
_ALWAYS = {"LineEvidenceNet": "evidence", "UprightNet": "upright", "UprightLinesNet": "upright_lines"}
#: the parser's argument of each network
_ROLES = {
    "ZSNet": "zsnet", "FSNet": "fsnet", "LineEvidenceNet": "evidence", "UprightNet": "upright",
    "UprightLinesNet": "upright_lines",
}

#: said where a network (a parser, say) is passed as a weight set
_PARSER_HINT = (
    "; a parser runs on tensors itself (parser(images)), or save its networks with "
    "ngp_kornia.nets.weights.save_network and pass those files"
)


@lru_cache(maxsize=8)
def _network(path: str) -> nn.Module:
    return load_network(path, network_name(path))


def check_weights(weights: object) -> list[nn.Module]:
    """The networks of a weight set, loaded once and shared read-only: a name of :data:`WEIGHTS` or the path of a
    ``.pt`` weights file (or a list of paths: one ZSNet and one FSNet file); every set has the shipped line evidence
    and orientation check unless a file of its own is given.

    Raises:
        ValueError: an unknown name, or something that is neither a name nor paths of ``.pt`` files.
        WeightsError: a missing, corrupt or mismatched weights file, or two files of one network.

    Example:
        >>> sorted(type(net).__name__ for net in check_weights("zsnet"))
        ['LineEvidenceNet', 'UprightLinesNet', 'UprightNet', 'ZSNet']
    """
    if weights is None or not isinstance(weights, (str, Path, list, tuple)):
        raise ValueError(
            f"weights must be one of {', '.join(WEIGHTS)} or the path of a .pt weights file (or a list of paths), "
            f"got {shown(weights)}{_PARSER_HINT if isinstance(weights, nn.Module) else ''}"
        )
    if isinstance(weights, str) and weights == "default":
        weights = DEFAULT_WEIGHTS
    if isinstance(weights, str) and weights in _NAMED:
        return [_network(str(shipped_weights(name))) for name in (*_NAMED[weights], *_ALWAYS.values())]
    paths = [weights] if isinstance(weights, (str, Path)) else list(weights)
    if not paths or not all(isinstance(p, Path) or str(p).endswith(".pt") for p in paths):
        raise ValueError(
            f"unknown weights {shown(weights)}; choose one of {', '.join(WEIGHTS)} or give paths to .pt weights files"
        )
    nets, seen = [], {}
    for path in paths:
        net = _network(str(path))
        name = type(net).__name__
        if name in seen:
            raise WeightsError(
                f"two {name} weights files given ({seen[name]}, {path}); give at most one file of each network"
            )
        seen[name] = path
        nets.append(net)
    for name, file in _ALWAYS.items():  # every weight set has these unless a file of its own is given
        if name not in seen:
            nets.append(_network(str(shipped_weights(file))))
    return nets


def network_roles(nets: list[nn.Module], copy: bool = True) -> dict[str, nn.Module]:
    """The networks of :func:`check_weights` by the parser's argument for each (``zsnet``, ``fsnet``, ``evidence``,
    ``upright``, ``upright_lines``); with ``copy``, the caller's own copies (training or moving them leaves the shared
    ones alone).

    Example:
        >>> sorted(network_roles(check_weights("none"), copy=False))
        ['evidence', 'upright', 'upright_lines']
    """
    return {_ROLES[type(net).__name__]: deepcopy(net) if copy else net for net in nets}


def checked_config(config: object) -> ParserConfig:
    """The settings a caller passed as ``config``: a :class:`ParserConfig`, a mapping of the settings to change
    (keys as :meth:`ParserConfig.replace` takes them), or None for the defaults.

    Raises:
        ConfigError: anything else, or an unknown setting or bad value in the mapping.

    Example:
        >>> checked_config({"horizon.refine": False}).horizon.refine
        False
    """
    if config is None:
        return ParserConfig()
    if isinstance(config, ParserConfig):
        return config
    if isinstance(config, Mapping) and all(isinstance(key, str) for key in config):
        return ParserConfig().replace(**config)
    raise ConfigError(
        f"config must be a ParserConfig, a mapping of settings such as {{'horizon.refine': False}}, or None; "
        f"got {shown(config)}"
    )


def weight_set_config(weights: object, config: object) -> ParserConfig:
    """The settings of a call: ``config`` as :func:`checked_config` takes it; for the ``"default"`` weight set with
    :data:`DEFAULT_SETTINGS` on top, unless a ``config`` mapping names them (a whole :class:`ParserConfig` cannot tell
    a setting left alone from one chosen: name it in a mapping, or choose ``weights="full"``, to turn one off).

    Example:
        >>> weight_set_config("default", None).evidence.enabled, weight_set_config("none", None).evidence.enabled
        (True, False)
        >>> weight_set_config("default", {"evidence.enabled": False}).evidence.enabled
        False
        >>> weight_set_config("default", ParserConfig()).evidence.enabled
        True
    """
    default = isinstance(weights, str) and weights == "default"
    if config is None:  # every call without a config: the settings checked once (a tenth of a millisecond a call)
        return _plain_config(tuple(DEFAULT_SETTINGS.items()) if default else ())
    settings = checked_config(config)
    if not default:
        return settings
    named = config if isinstance(config, Mapping) else {}
    return settings.replace(**{key: value for key, value in DEFAULT_SETTINGS.items() if key not in named})


@lru_cache(maxsize=4)
def _plain_config(changes: tuple) -> ParserConfig:
    """The default settings with ``changes`` (pairs of setting and value); the settings are frozen, so one object
    serves every call."""
    return ParserConfig().replace(**dict(changes))
