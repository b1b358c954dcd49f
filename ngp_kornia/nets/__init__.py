"""The learned modules: the line-evidence network and its inputs. Knows the geometry; nothing else of the package."""

from ngp_kornia.nets.line_evidence import DIRECTION_CLASSES, LineEvidenceNet, structure_weights
from ngp_kornia.nets.line_features import FEATURE_NAMES, segment_features

__all__ = ["DIRECTION_CLASSES", "FEATURE_NAMES", "LineEvidenceNet", "segment_features", "structure_weights"]
