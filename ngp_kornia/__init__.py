"""ngp-kornia: single-image camera calibration for man-made scenes (Neural Geometric Parser, ECCV 2020).

>>> import ngp_kornia
>>> callable(ngp_kornia.calibrate)
True
"""

import os as _os

# OpenCV's own pixel limit, the backstop for image formats whose header ngp_kornia.io does not parse: the same value
# as ngp_kornia.io.MAX_PIXELS. OpenCV reads it once, so it applies when ngp_kornia is imported before cv2.
_os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(2**27))

from ngp_kornia.api import calibrate  # noqa: E402
from ngp_kornia.errors import (  # noqa: E402
    CheckpointError,
    ConfigError,
    ImageReadError,
    InputError,
    ManifestError,
    NGPError,
    OutputError,
    WeightsError,
)
from ngp_kornia.io import ImageError  # noqa: E402
from ngp_kornia.models import Calibration, NeuralGeometricParser, ParserConfig  # noqa: E402

__version__ = "0.1.0"
__all__ = [
    "Calibration",
    "CheckpointError",
    "ConfigError",
    "ImageError",
    "ImageReadError",
    "InputError",
    "ManifestError",
    "NGPError",
    "NeuralGeometricParser",
    "OutputError",
    "ParserConfig",
    "WeightsError",
    "__version__",
    "calibrate",
]
