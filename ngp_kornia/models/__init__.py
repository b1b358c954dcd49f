"""Networks and the parser pipeline (plain nn.Modules, no training code)."""

from ngp_kornia.models.fsnet import FSNet
from ngp_kornia.models.parser import NeuralGeometricParser, ParserConfig
from ngp_kornia.models.result import Calibration
from ngp_kornia.models.trace import ParserTrace
from ngp_kornia.models.zsnet import ZSNet

__all__ = ["Calibration", "FSNet", "NeuralGeometricParser", "ParserConfig", "ParserTrace", "ZSNet"]
