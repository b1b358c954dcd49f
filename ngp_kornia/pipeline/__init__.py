"""The calibration pipeline: its non-learned stages, one per module, and the parser that runs them with the networks
of :mod:`ngp_kornia.nets` (plain ``nn.Module``s, no training code)."""

from ngp_kornia.pipeline.parser import NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.trace import ParserTrace

__all__ = ["Calibration", "NeuralGeometricParser", "ParserConfig", "ParserTrace"]
