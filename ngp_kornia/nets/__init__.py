"""The learned modules: ZSNet, FSNet and its trunk, the line-evidence network and its inputs, and the reading and
writing of their weights files. Knows the geometry; nothing else of the package."""

from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.line_evidence import DIRECTION_CLASSES, LineEvidenceNet, structure_weights
from ngp_kornia.nets.line_features import FEATURE_NAMES, segment_features
from ngp_kornia.nets.zsnet import ZSNet

__all__ = [
    "DIRECTION_CLASSES",
    "FEATURE_NAMES",
    "FSNet",
    "LineEvidenceNet",
    "ZSNet",
    "segment_features",
    "structure_weights",
]
