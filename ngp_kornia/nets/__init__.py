"""The learned modules: ZSNet, FSNet and its trunk, and the reading and writing of their weights files."""

from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.zsnet import ZSNet

__all__ = ["FSNet", "ZSNet"]
