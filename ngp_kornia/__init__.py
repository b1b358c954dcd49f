"""ngp-kornia: single-image camera calibration for man-made scenes (Neural Geometric Parser, ECCV 2020).

>>> import ngp_kornia
>>> callable(ngp_kornia.calibrate)
True
"""

from ngp_kornia.api import calibrate
from ngp_kornia.io import ImageError
from ngp_kornia.models import Calibration, NeuralGeometricParser, ParserConfig

__version__ = "0.1.0"
__all__ = ["Calibration", "ImageError", "NeuralGeometricParser", "ParserConfig", "calibrate", "__version__"]
