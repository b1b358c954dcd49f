"""The calibration pipeline: its non-learned stages, one per module, their settings, and the parser that runs them
with the networks of :mod:`ngp_kornia.nets` (plain ``nn.Module``s, no training code).

The names below are imported on first use, so the settings (:mod:`ngp_kornia.pipeline.settings`, which imports
nothing heavy) can be read before torch loads.
"""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ngp_kornia.pipeline.parser import NeuralGeometricParser
    from ngp_kornia.pipeline.priors import Priors
    from ngp_kornia.pipeline.result import Calibration
    from ngp_kornia.pipeline.settings import (
        EvidenceSettings,
        HorizonSettings,
        ParserConfig,
        PolishSettings,
        SamplingSettings,
        ScoringSettings,
        SegmentSettings,
        TrustSettings,
    )
    from ngp_kornia.pipeline.trace import ParserTrace

_HOMES = {
    "NeuralGeometricParser": "parser",
    "Priors": "priors",
    "Calibration": "result",
    "ParserTrace": "trace",
    **dict.fromkeys(
        ("EvidenceSettings", "HorizonSettings", "ParserConfig", "PolishSettings", "SamplingSettings", "ScoringSettings")
        + ("SegmentSettings", "TrustSettings"),
        "settings",
    ),
}

__all__ = [
    "Calibration",
    "EvidenceSettings",
    "HorizonSettings",
    "NeuralGeometricParser",
    "ParserConfig",
    "ParserTrace",
    "PolishSettings",
    "Priors",
    "SamplingSettings",
    "ScoringSettings",
    "SegmentSettings",
    "TrustSettings",
]


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
