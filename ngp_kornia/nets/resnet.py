"""A small configurable ResNet (He et al., CVPR 2016) built from basic blocks: the backbone of FSNet.

Any module can replace it as an FSNet backbone if it follows the same interface:

* attribute ``in_channels``: channels of the input it expects;
* attribute ``out_channels``: channels of the feature map it returns;
* ``forward(x)``: (N, in_channels, H, W) -> (N, out_channels, h, w) feature map (any output stride; FSNet pools
  or resizes to whatever ``h, w`` come out).

Normalisation is selectable: ``"batch"`` (BatchNorm, fastest at inference since it is a fixed affine map in eval
mode, but its training statistics are poor over a batch of one or two images) or ``"group"`` (GroupNorm, independent
of the batch, so the same in training and evaluation and with any batch size).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor, nn

__all__ = ["LAYOUTS", "BasicBlock", "Conv3x3", "ResNet", "make_norm"]

#: named (widths, depths) layouts; "resnet18" is the standard ResNet-18 trunk
LAYOUTS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "resnet18": ((64, 128, 256, 512), (2, 2, 2, 2)),
    "resnet10": ((64, 128, 256, 512), (1, 1, 1, 1)),
    "resnet18-half": ((32, 64, 128, 256), (2, 2, 2, 2)),
    "resnet18-half-s16": ((32, 64, 128), (2, 2, 2)),  # the first three stages only: stride 16
    "resnet10-half-s16": ((32, 64, 128), (1, 1, 1)),
}


def make_norm(kind: str, channels: int) -> nn.Module:
    """A normalisation layer: ``"batch"`` (BatchNorm2d) or ``"group"`` (GroupNorm with at most 32 groups of at least
    8 channels each, the group count dividing ``channels``).

    Example:
        >>> make_norm("group", 64).num_groups
        8
    """
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "group":
        groups = min(32, max(1, channels // 8))
        while channels % groups:
            groups -= 1
        return nn.GroupNorm(groups, channels)
    raise ValueError(f"unknown norm {kind!r}: use 'batch' or 'group'")


class Conv3x3(nn.Conv2d):
    """A 3x3 ``nn.Conv2d`` (no bias) that takes oneDNN's kernel for inference on the CPU whatever the input's size.

    For float32 inputs of fewer than about 20k values (one image's 16x16 or 8x8 maps of the later stages) torch
    picks its im2col path, 1.5-2x slower there than oneDNN's direct kernel; training, other dtypes and devices take
    torch's choice. The two kernels round differently (relative 1e-7).

    Example:
        >>> conv = Conv3x3(8, 8, stride=1).eval()
        >>> with torch.no_grad():
        ...     fast = conv(torch.rand(1, 8, 6, 6))
        >>> fast.shape
        torch.Size([1, 8, 6, 6])
    """

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1) -> None:
        super().__init__(in_channels, out_channels, 3, stride, 1, bias=False)

    def _conv_forward(self, input: Tensor, weight: Tensor, bias: Tensor | None) -> Tensor:
        if _onednn_fits(input, weight):
            return torch.mkldnn_convolution(input, weight, bias, self.padding, self.stride, self.dilation, self.groups)
        return super()._conv_forward(input, weight, bias)


def _onednn_fits(input: Tensor, weight: Tensor) -> bool:
    """Whether a convolution may run through ``torch.mkldnn_convolution`` directly: float32 on the CPU, with oneDNN
    enabled and no gradient to record."""
    return (
        input.device.type == "cpu" and input.dtype == torch.float32 and weight.dtype == torch.float32
        and not (torch.is_grad_enabled() and (input.requires_grad or weight.requires_grad))
        and torch.backends.mkldnn.is_available() and torch.backends.mkldnn.enabled
    )  # fmt: skip


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual connection (a 1x1 projection when the shape changes).

    Args:
        in_channels: input channels.
        out_channels: output channels.
        stride: stride of the first convolution (and of the projection).
        norm: ``"batch"`` or ``"group"``.

    Example:
        >>> BasicBlock(8, 16, stride=2)(torch.rand(1, 8, 10, 10)).shape
        torch.Size([1, 16, 5, 5])
    """

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1, norm: str = "batch") -> None:
        super().__init__()
        self.conv1 = Conv3x3(in_channels, out_channels, stride)
        self.norm1 = make_norm(norm, out_channels)
        self.conv2 = Conv3x3(out_channels, out_channels)
        self.norm2 = make_norm(norm, out_channels)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or in_channels != out_channels:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, 1, stride, bias=False), make_norm(norm, out_channels)
            )

    def forward(self, x: Tensor) -> Tensor:
        out = self.relu(self.norm1(self.conv1(x)))
        out = self.norm2(self.conv2(out))
        return self.relu(out + self.shortcut(x))


class ResNet(nn.Module):
    """ResNet trunk: a 7x7 stride-2 stem convolution and a 3x3 stride-2 max pool (stride 4), then one stage of
    :class:`BasicBlock` per entry of ``widths``, every stage after the first halving the resolution. No classifier:
    :meth:`forward` returns the last feature map, :meth:`pooled` its global average.

    Args:
        in_channels: input channels (3 for RGB; FSNet stacks more).
        widths: channels of each stage (the stem has ``widths[0]``).
        depths: blocks per stage, same length as ``widths``. ``(64, 128, 256, 512)`` with ``(2, 2, 2, 2)`` is
            ResNet-18 (:data:`LAYOUTS`).
        norm: ``"batch"`` or ``"group"`` (see the module notes).
        zero_init_residual: start every block's last norm at zero scale, so blocks begin as identities.

    Attributes:
        out_channels: ``widths[-1]``.
        stride: output stride, ``4 * 2 ** (len(widths) - 1)``.

    Example:
        >>> net = ResNet(in_channels=4, widths=(8, 16, 32), depths=(1, 1, 1), norm="group")
        >>> net(torch.rand(2, 4, 64, 64)).shape, net.stride, net.pooled(torch.rand(2, 4, 64, 64)).shape
        (torch.Size([2, 32, 4, 4]), 16, torch.Size([2, 32]))
    """

    def __init__(
        self,
        in_channels: int = 3,
        widths: Sequence[int] = (64, 128, 256, 512),
        depths: Sequence[int] = (2, 2, 2, 2),
        norm: str = "batch",
        zero_init_residual: bool = False,
    ) -> None:
        super().__init__()
        KORNIA_CHECK(len(widths) == len(depths) and len(widths) > 0, "widths and depths need the same, non-zero length")
        KORNIA_CHECK(all(d >= 1 for d in depths), f"every stage needs at least one block, got depths {depths}")
        self.in_channels, self.widths, self.depths = in_channels, tuple(widths), tuple(depths)
        self.norm, self.zero_init_residual = norm, zero_init_residual
        self.out_channels = self.widths[-1]
        self.stride = 4 * 2 ** (len(self.widths) - 1)
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, self.widths[0], 7, 2, 3, bias=False),
            make_norm(norm, self.widths[0]),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        stages, channels = [], self.widths[0]
        for i, (width, depth) in enumerate(zip(self.widths, self.depths, strict=True)):
            blocks = [BasicBlock(channels, width, 1 if i == 0 else 2, norm)]
            blocks += [BasicBlock(width, width, 1, norm) for _ in range(depth - 1)]
            stages.append(nn.Sequential(*blocks))
            channels = width
        self.stages = nn.Sequential(*stages)
        self._init_weights()

    def _init_weights(self) -> None:
        if self.stem[0].weight.is_meta:  # shapes only: drawing on the meta device imports torch._dynamo (1-2 s)
            return
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d | nn.GroupNorm):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        if self.zero_init_residual:
            for m in self.modules():
                if isinstance(m, BasicBlock):
                    nn.init.zeros_(m.norm2.weight)

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network."""
        return {
            "in_channels": self.in_channels,
            "widths": list(self.widths),
            "depths": list(self.depths),
            "norm": self.norm,
            "zero_init_residual": self.zero_init_residual,
        }

    def forward(self, x: Tensor) -> Tensor:
        """Feature map: (N, in_channels, H, W) -> (N, out_channels, ~H / stride, ~W / stride)."""
        KORNIA_CHECK_SHAPE(x, ["N", "C", "H", "W"])
        KORNIA_CHECK(x.shape[1] == self.in_channels, f"expected {self.in_channels} input channels, got {x.shape[1]}")
        return self.stages(self.stem(x))

    def pooled(self, x: Tensor) -> Tensor:
        """Globally average-pooled features: (N, in_channels, H, W) -> (N, out_channels)."""
        return self.forward(x).mean((-2, -1))
