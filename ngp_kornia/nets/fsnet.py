r"""FSNet, the frame scoring network of Sec. 3.2 (Eq. 13-20): scores how well each Manhattan-frame candidate (three
VPs and a focal length) fits an image, from the image, its line map L (Eq. 13) and the candidate's closeness maps
A_x, A_y, A_z (Eq. 14-15). ``sigmoid`` of the output estimates the score :math:`s_{vh}` of Eq. 20.

Two variants share one interface (:class:`FSNet` with ``variant=...``):

* ``"faithful"``, the paper's network: a ResNet over a 17-channel tensor per candidate (3 image + 1 line map +
  3 closeness maps + 10 constant planes holding the candidate's 9 VP coordinates and its focal length), globally
  pooled, then a linear layer. One full CNN pass per candidate, so its cost grows linearly with the candidates
  (about 2.4 GMAC per candidate with the default ResNet-18 at 224 x 224: the 17-channel 7x7 stem alone is 0.67).
* ``"shared"``: the trunk runs once per image on the image and the line map (4 channels) to a stride-16 feature
  map; each candidate only adds a light head on that low-resolution map: its closeness maps are average-pooled to
  the trunk's resolution (as line density and as mean closeness of the line pixels, a local form of Eq. 21), its
  VPs and focal length go through an MLP, and two 3x3 convolutions, global average and max pooling and an MLP give
  the score. Scoring many candidates then costs little more than scoring one.

Both are equivariant to the candidates' order (each candidate is scored independently; with BatchNorm, in eval
mode) and differentiable with respect to every input.

The ablations of the paper's Table 4 are constructor switches: ``use_image=False`` ("FSNet w/o image") drops the
image channels, ``use_maps=False`` ("w/o L and A") drops the line and closeness maps; inputs that are dropped are
still passed (one interface) but ignored.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from kornia.core.check import KORNIA_CHECK, KORNIA_CHECK_SHAPE
from torch import Tensor, nn

from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.nets.fsnet_inputs import (
    NUM_PARAMS,
    NUM_SUPPORT,
    VARIANTS,
    FSNetImageInputs,
    FSNetInputs,
    area_resize,
    fsnet_frame_inputs,
    fsnet_image_inputs,
    fsnet_line_inputs,
)
from ngp_kornia.nets.resnet import LAYOUTS, ResNet

__all__ = ["FSNet"]


_DEFAULT_LAYOUT = {"faithful": LAYOUTS["resnet18"], "shared": LAYOUTS["resnet18-half-s16"]}
_DEFAULT_NORM = {"faithful": "batch", "shared": "group"}


def _mlp(sizes: Sequence[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class FSNet(nn.Module):
    """Frame scoring network (Sec. 3.2), in the paper's per-candidate form or with a shared image trunk.

    Input channels (:attr:`in_channels`, the backbone's input):

    =================  ==============================  ==================================
    switches           ``"faithful"`` (per candidate)  ``"shared"`` (trunk, once/image)
    =================  ==============================  ==================================
    default            17 = 3 image + 1 L + 3 A + 10   4 = 3 image + 1 L
    use_image=False    14 = 1 L + 3 A + 10             1 = L
    use_maps=False     13 = 3 image + 10               3 = image
    both False         10 = params planes              0 (no trunk: params MLP only)
    =================  ==============================  ==================================

    In the shared variant each candidate's head also takes 6 low-resolution map channels (A pooled as line density
    and as mean closeness over line pixels; dropped with ``use_maps=False``) and the 10 parameters (30 with
    ``use_support``).

    Args:
        variant: ``"faithful"`` or ``"shared"`` (see the module notes).
        widths: backbone stage widths; default ResNet-18's ``(64, 128, 256, 512)`` for faithful, ``(32, 64, 128)``
            (stride 16) for shared. Two stages give a stride-8 trunk.
        depths: blocks per stage; default ``(2, 2, 2, 2)`` for faithful, ``(2, 2, 2)`` for shared (the first three
            stages of ResNet-18 at half width).
        norm: ``"batch"`` or ``"group"`` for the backbone; default BatchNorm for faithful (its statistics come from
            each backbone pass, B times the chunk's candidates, and it is a free affine map at inference) and
            GroupNorm for shared, whose trunk only sees the B images of a batch (the paper trains with B = 2).
        head_width: channels of the shared variant's head.
        input_size: the side the inputs are built at (:meth:`prepare_inputs`); the network itself is fully
            convolutional and accepts any size.
        use_image: feed the image (False: "FSNet w/o image").
        use_maps: feed L and A (False: "FSNet w/o L and A").
        use_support: also give each candidate its exact line support (:func:`frame_support`, 20 values) with its
            parameters (30 instead of 10; in the faithful variant as 20 more constant planes). The maps are drawn at
            the network's resolution, where frames a few pixels apart look the same; the support tells them apart.
        kernel_angle: closeness kernel of the inputs (:func:`fsnet_inputs`); None for Eq. 14.
        chunk_size: at most this many candidate images per backbone pass (faithful) or head pass (shared), so
            memory at inference does not grow with the candidates. (With gradients every pass stays in memory.)
        backbone: a custom backbone (interface in :mod:`ngp_kornia.nets.resnet`) replacing the built-in ResNet;
            its ``in_channels`` must match the table. Such a network has no :meth:`settings`.

    Example:
        >>> net = FSNet("shared", widths=(8, 16), depths=(1, 1), head_width=8).eval()
        >>> x = (torch.rand(2, 3, 64, 64), torch.rand(2, 1, 64, 64), torch.rand(2, 5, 3, 64, 64), torch.rand(2, 5, 10))
        >>> net(*x).shape, net.in_channels
        (torch.Size([2, 5]), 4)
    """

    def __init__(
        self,
        variant: str = "shared",
        widths: Sequence[int] | None = None,
        depths: Sequence[int] | None = None,
        norm: str | None = None,
        head_width: int = 32,
        input_size: int = 224,
        use_image: bool = True,
        use_maps: bool = True,
        use_support: bool = False,
        kernel_angle: float | None = 88.0,
        chunk_size: int = 32,
        backbone: nn.Module | None = None,
    ) -> None:
        super().__init__()
        KORNIA_CHECK(variant in VARIANTS, f"unknown FSNet variant {variant!r}: use one of {VARIANTS}")
        KORNIA_CHECK(chunk_size > 0, "chunk_size must be positive")
        self.variant, self.head_width, self.input_size, self.chunk_size = variant, head_width, input_size, chunk_size
        self.use_image, self.use_maps, self.kernel_angle = use_image, use_maps, kernel_angle
        self.use_support = use_support
        self.num_params = NUM_PARAMS + (NUM_SUPPORT if use_support else 0)
        layout = _DEFAULT_LAYOUT[variant]
        self.widths = tuple(layout[0] if widths is None else widths)
        self.depths = tuple(layout[1] if depths is None else depths)
        self.norm = _DEFAULT_NORM[variant] if norm is None else norm
        self.custom_backbone = backbone is not None
        image_ch = 3 if use_image else 0
        if variant == "faithful":
            self.in_channels = image_ch + (4 if use_maps else 0) + self.num_params
        else:
            self.in_channels = image_ch + (1 if use_maps else 0)
        if backbone is None and self.in_channels > 0:
            backbone = ResNet(self.in_channels, self.widths, self.depths, self.norm)
            if variant == "shared":  # its trunk runs channels-last (_trunk): so do its weights, sparing a conversion
                backbone = backbone.to(memory_format=torch.channels_last)
        if backbone is not None:
            got = getattr(backbone, "in_channels", self.in_channels)
            KORNIA_CHECK(got == self.in_channels, f"the backbone takes {got} channels, FSNet feeds {self.in_channels}")
        self.backbone = backbone
        feat = 0 if backbone is None else int(backbone.out_channels)
        if variant == "faithful":
            self.fc = nn.Linear(feat, 1)
            return
        d = head_width
        self.context = nn.Conv2d(feat, d, 1) if backbone is not None else None
        self.map_proj = nn.Conv2d(6, d, 1, bias=False) if use_maps else None
        self.param_mlp = _mlp([self.num_params, d, d])
        self.conv1 = nn.Conv2d(d, d, 3, padding=1)
        self.conv2 = nn.Conv2d(d, d, 3, padding=1)
        self.scorer = _mlp([2 * d, d, 1])
        if backbone is not None and not self.custom_backbone:
            # the head adds every candidate's maps to the trunk's channels-last context map: channels-last weights
            # give its convolutions channels-last outputs and spare a weight conversion per call (the same values)
            for conv in (self.map_proj, self.conv1, self.conv2):
                if conv is not None:
                    conv.to(memory_format=torch.channels_last)

    def settings(self) -> dict:
        """The constructor arguments that rebuild this network (stored with its weights)."""
        if self.custom_backbone:
            raise ValueError("an FSNet with a custom backbone cannot be rebuilt from settings; save the module itself")
        return {
            "variant": self.variant,
            "widths": list(self.widths),
            "depths": list(self.depths),
            "norm": self.norm,
            "head_width": self.head_width,
            "input_size": self.input_size,
            "use_image": self.use_image,
            "use_maps": self.use_maps,
            "use_support": self.use_support,
            "kernel_angle": self.kernel_angle,
            "chunk_size": self.chunk_size,
        }

    def prepare_inputs(
        self,
        images: Tensor,
        segments: Tensor,
        mask: Tensor,
        frames: FrameCandidates,
        lines: Tensor | None = None,
        image_inputs: FSNetImageInputs | None = None,
    ) -> FSNetInputs:
        """:func:`fsnet_inputs` at this network's input size and closeness kernel; the shared variant gets its
        closeness maps already pooled to the trunk's resolution (the same scores, without the full maps).
        ``lines``: the segments' pseudo-camera lines when already computed; ``image_inputs``: the frame-free part
        (:meth:`prepare_image_inputs`) when already built."""
        if image_inputs is None:
            image_inputs = self.prepare_image_inputs(images, segments, mask)
        return fsnet_frame_inputs(
            image_inputs, segments, mask, frames, self.kernel_angle, self.chunk_size, self.use_support, lines
        )

    def prepare_image_inputs(self, images: Tensor, segments: Tensor, mask: Tensor) -> FSNetImageInputs:
        """The part of :meth:`prepare_inputs` that needs no frame candidate (:func:`fsnet_image_inputs`)."""
        size = self.input_size
        return fsnet_image_inputs(images, segments, mask, size, pool=self.pool_cell(size, size))

    def input_images(self, images: Tensor) -> Tensor:
        """The (B, 3, H, W) images as :meth:`prepare_image_inputs` puts them in its inputs: resized to the network's
        input (:func:`~ngp_kornia.nets.fsnet_inputs.with_images`); for :meth:`prepare_line_inputs`' ``images``."""
        size = (self.input_size, self.input_size)
        return images if tuple(images.shape[-2:]) == size else area_resize(images, size)

    def prepare_line_inputs(self, segments: Tensor, mask: Tensor, image_size: tuple[int, int]) -> FSNetImageInputs:
        """:meth:`prepare_image_inputs` without the image (:func:`fsnet_line_inputs`; :func:`with_images` adds
        it), for segments of an ``image_size`` (H, W) image."""
        size = self.input_size
        return fsnet_line_inputs(segments, mask, image_size, size, pool=self.pool_cell(size, size))

    def image_context(self, image_inputs: FSNetImageInputs) -> tuple[Tensor | None, Tensor | None] | None:
        """What the shared trunk makes of an image before any candidate (for ``forward(..., context=...)``): its
        context map and the line map pooled to it; None where the trunk needs the full maps of :meth:`forward`'s
        arguments (the faithful variant, or maps drawn at full resolution)."""
        if self.variant == "faithful" or image_inputs.drawn is None:
            return None
        return self._trunk(image_inputs.images, image_inputs.drawn.line_map)

    def pool_cell(self, height: int, width: int) -> int | None:
        """The cell size (the trunk's stride) at which the shared variant takes pooled closeness maps for an input
        of this size, or None where it needs full maps (faithful variant, custom backbone, no maps, or a size that
        is not a multiple of the stride)."""
        stride = getattr(self.backbone, "stride", None) if not self.custom_backbone else None
        if self.variant != "shared" or not self.use_maps or stride is None:
            return None
        return stride if height % stride == 0 and width % stride == 0 else None

    def forward(
        self,
        images: Tensor,
        line_map: Tensor,
        closeness: Tensor,
        params: Tensor,
        context: tuple[Tensor | None, Tensor | None] | None = None,
    ) -> Tensor:
        """Score frame candidates.

        Args:
            images: (B, 3, H, W) RGB in [0, 1].
            line_map: (B, 1, H, W) line map L (Eq. 13).
            closeness: (B, F, 3, H, W) closeness maps A_x, A_y, A_z per candidate (Eq. 15); the shared variant
                also takes them pooled to (B, F, 3, H / c, W / c) with ``c`` = :meth:`pool_cell`.
            params: (B, F, 10) per candidate: three unit VPs (pseudo camera, row-major) and the focal length.
            context: the shared trunk's output for these images and line map (:meth:`image_context`) when already
                computed; None runs the trunk.

        Returns:
            (B, F) logits; ``sigmoid`` estimates s_vh (Eq. 20).
        """
        KORNIA_CHECK_SHAPE(images, ["B", "3", "H", "W"])
        KORNIA_CHECK_SHAPE(line_map, ["B", "1", "H", "W"])
        KORNIA_CHECK_SHAPE(closeness, ["B", "F", "3", "H", "W"])
        KORNIA_CHECK_SHAPE(params, ["B", "F", str(self.num_params)])
        B, _, H, W = images.shape
        KORNIA_CHECK(
            line_map.shape[0] == B and line_map.shape[-2:] == (H, W) and closeness.shape[0] == B,
            "images, line_map and closeness must share batch and size",
        )
        cell = self.pool_cell(H, W)
        pooled = cell is not None and closeness.shape[-2:] == (H // cell, W // cell)
        KORNIA_CHECK(
            closeness.shape[-2:] == (H, W) or pooled,
            "closeness maps must have the images' size" + (f" or be pooled by {cell}" if cell else ""),
        )
        KORNIA_CHECK(params.shape[:2] == closeness.shape[:2], "params and closeness must share (B, F)")
        num = params.shape[1]
        if num == 0:
            return params.new_zeros(B, 0)
        step = max(1, self.chunk_size // B)
        if self.variant == "faithful":
            chunks = [
                self._faithful(images, line_map, closeness[:, i : i + step], params[:, i : i + step])
                for i in range(0, num, step)
            ]
        else:
            context, low_l = self._trunk(images, line_map) if context is None else context
            chunks = [
                self._head(context, low_l, closeness[:, i : i + step], params[:, i : i + step], W)
                for i in range(0, num, step)
            ]
        return torch.cat(chunks, 1)

    def _faithful(self, images: Tensor, line_map: Tensor, closeness: Tensor, params: Tensor) -> Tensor:
        B, c, _, H, W = closeness.shape
        parts = []
        if self.use_image:
            parts.append(images[:, None].expand(B, c, 3, H, W))
        if self.use_maps:
            parts += [line_map[:, None].expand(B, c, 1, H, W), closeness]
        parts.append(params[..., None, None].expand(B, c, self.num_params, H, W))
        x = torch.cat(parts, 2).flatten(0, 1)
        feats = self.backbone(x)
        return self.fc(feats.mean((-2, -1))).reshape(B, c)

    def _trunk(self, images: Tensor, line_map: Tensor) -> tuple[Tensor | None, Tensor | None]:
        """Once per image: the trunk's context map (B, D, h, w) and the line map pooled to it (B, 1, h, w)."""
        if self.backbone is None:
            return None, None
        parts = ([images] if self.use_image else []) + ([line_map] if self.use_maps else [])
        # channels-last lets the CPU convolutions take their faster kernels (the same values to float round-off)
        feats = self.backbone(torch.cat(parts, 1).contiguous(memory_format=torch.channels_last))
        low_l = F.adaptive_avg_pool2d(line_map, feats.shape[-2:]) if self.use_maps else None
        return self.context(feats), low_l

    def _head(
        self, context: Tensor | None, low_l: Tensor | None, closeness: Tensor, params: Tensor, width: int
    ) -> Tensor:
        B, c = params.shape[:2]
        # without autograd the sums and ReLUs reuse the fresh maps they read: allocating a new one (128 KB for 16
        # candidates) costs more than the arithmetic
        inplace = not torch.is_grad_enabled()
        x = self.param_mlp(params)[..., None, None]  # (B, c, D, 1, 1)
        if context is not None:
            x = x + context[:, None]
        if self.map_proj is not None and low_l is not None:
            h, w = low_l.shape[-2:]
            low_a = closeness.flatten(0, 1)
            if low_a.shape[-2:] != (h, w):
                low_a = F.adaptive_avg_pool2d(low_a, (h, w))
            low_a = low_a.reshape(B, c, 3, h, w)
            density = low_a * (width / w)  # about the length of line per cell, in cells
            mean = low_a / low_l[:, None].clamp_min(1e-6)  # mean closeness of the cell's line pixels (local Eq. 21)
            maps = torch.cat([density, mean], 2).flatten(0, 1)
            proj = self.map_proj(maps).reshape(B, c, -1, h, w)
            x = proj.add_(x) if inplace else x + proj
        x = x.flatten(0, 1).relu_() if inplace else torch.relu(x.flatten(0, 1))
        if inplace:
            y = self.conv2(self.conv1(x).relu_()).add_(x).relu_()
        else:
            y = torch.relu(self.conv2(torch.relu(self.conv1(x))) + x)
        pooled = torch.cat([y.mean((-2, -1)), y.amax((-2, -1))], -1)
        return self.scorer(pooled).reshape(B, c)
