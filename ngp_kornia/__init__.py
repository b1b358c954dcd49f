"""ngp-kornia: single-image camera calibration for man-made scenes (Neural Geometric Parser, ECCV 2020).

>>> import ngp_kornia
>>> callable(ngp_kornia.calibrate)
True
"""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ngp_kornia.api import calibrate
    from ngp_kornia.errors import (
        CheckpointError,
        ConfigError,
        ImageReadError,
        InputError,
        ManifestError,
        NGPError,
        NGPWarning,
        OutputError,
        WeightsError,
    )
    from ngp_kornia.io import ImageError
    from ngp_kornia.pipeline import (
        Calibration,
        EvidenceSettings,
        HorizonSettings,
        NeuralGeometricParser,
        ParserConfig,
        PolishSettings,
        Priors,
        SamplingSettings,
        ScoringSettings,
        SegmentSettings,
        TrustSettings,
    )

# The public names are imported on first use (torch and OpenCV take a second or two to import): the ``ngp``
# command can then answer Ctrl+C during its start-up with a message instead of a traceback.
_PIPELINE = (
    "Calibration EvidenceSettings HorizonSettings NeuralGeometricParser ParserConfig PolishSettings Priors "
    "SamplingSettings ScoringSettings SegmentSettings TrustSettings"
)
_ERRORS = (
    "CheckpointError ConfigError ImageReadError InputError ManifestError NGPError NGPWarning OutputError WeightsError"
)
_HOMES = {
    "calibrate": "ngp_kornia.api",
    "ImageError": "ngp_kornia.io",
    **dict.fromkeys(_PIPELINE.split(), "ngp_kornia.pipeline"),
    **dict.fromkeys(_ERRORS.split(), "ngp_kornia.errors"),
}

__version__ = "0.1.0"
__all__ = [
    "Calibration",
    "CheckpointError",
    "ConfigError",
    "EvidenceSettings",
    "HorizonSettings",
    "ImageError",
    "ImageReadError",
    "InputError",
    "ManifestError",
    "NGPError",
    "NGPWarning",
    "NeuralGeometricParser",
    "OutputError",
    "ParserConfig",
    "PolishSettings",
    "Priors",
    "SamplingSettings",
    "ScoringSettings",
    "SegmentSettings",
    "TrustSettings",
    "WeightsError",
    "__version__",
    "calibrate",
]


def __getattr__(name: str):
    import importlib
    import importlib.util

    if name in _HOMES:
        value = getattr(importlib.import_module(_HOMES[name]), name)
    elif not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")  # a submodule, as the eager imports made them
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
