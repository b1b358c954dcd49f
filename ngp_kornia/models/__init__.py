"""Networks and the parser pipeline (plain nn.Modules, no training code)."""

from ngp_kornia.models.parser import NeuralGeometricParser, ParserConfig
from ngp_kornia.models.result import Calibration

__all__ = ["Calibration", "NeuralGeometricParser", "ParserConfig"]
