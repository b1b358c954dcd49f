"""The calibration result: a typed, batched container of tensors with attribute access."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

__all__ = ["Calibration"]


@dataclass
class Calibration:
    """Camera calibration of one image or a batch (every field has a leading batch dim ``B`` when batched).

    Conventions: pixels x right, y down, origin at the centre of the top-left pixel, in the *input* image's
    pixels; camera frame x right, y down, z forward; ``R`` maps world directions to camera directions with world y
    pointing down; pitch > 0 looks up; roll > 0 when the scene's up direction leans right in the image; angles in
    degrees. See :mod:`ngp_kornia.geometry.camera`.

    Attributes:
        K: (B, 3, 3) intrinsics (principal point at the image centre).
        R: (B, 3, 3) world-to-camera rotation of the Manhattan frame; world z is the horizontal scene axis closest
            to the optical axis, so yaw lies in [-45, 45].
        focal: (B,) focal length in pixels.
        fov_v: (B,) vertical field of view, degrees.
        fov_h: (B,) horizontal field of view, degrees.
        pitch: (B,) degrees.
        roll: (B,) degrees.
        yaw: (B,) degrees, relative to the scene's Manhattan frame.
        up: (B, 3) unit up vector in camera coordinates.
        zenith: (B, 3) homogeneous zenith VP in pixels (unit norm; third coordinate 0 when at infinity).
        horizon: (B, 3) horizon line ``(a, b, c)``, ``a x + b y + c = 0`` in pixels, ``a^2 + b^2 = 1``, ``b >= 0``.
        vps: (B, 3, 3) the three Manhattan VPs, homogeneous pixels, unit norm; row ``i`` is the VP of world axis
            ``i`` (row 1 is the zenith direction).
        score: (B,) score of the best frame candidate (the Manhattan score for the geometric path), in [0, 1].
        valid: (B,) bool; False when the image offered no valid frame candidate, in which case the result is a
            level camera with a 60 degree field of view on the long side.
        image_size: (B, 2) ``(height, width)`` in pixels.
        exif_orientation: (B,) long: the EXIF orientation tag (1-8) of the file that was applied before
            calibrating, so every field is in the pixels of the image as displayed (6 and 8: a phone photo stored
            turned, ...); 1 when nothing was turned: files stored upright, and arrays and tensors, which are taken
            as they are.
    """

    K: Tensor
    R: Tensor
    focal: Tensor
    fov_v: Tensor
    fov_h: Tensor
    pitch: Tensor
    roll: Tensor
    yaw: Tensor
    up: Tensor
    zenith: Tensor
    horizon: Tensor
    vps: Tensor
    score: Tensor
    valid: Tensor
    image_size: Tensor
    exif_orientation: Tensor | None = None

    def __post_init__(self) -> None:
        if self.exif_orientation is None:  # made without it: nothing was turned
            self.exif_orientation = torch.ones_like(self.focal, dtype=torch.long)

    @property
    def batched(self) -> bool:
        return self.focal.dim() == 1

    def __len__(self) -> int:
        if not self.batched:
            raise TypeError("an unbatched Calibration has no length")
        return self.focal.shape[0]

    def __getitem__(self, index: int) -> Calibration:
        """The calibration of one image of a batch, without the batch dim."""
        if not self.batched:
            raise TypeError("an unbatched Calibration cannot be indexed")
        return Calibration(**{f.name: _index(getattr(self, f.name), index) for f in fields(self)})

    def to(self, *args, **kwargs) -> Calibration:
        """Move or cast every floating-point tensor, like :meth:`torch.Tensor.to`."""
        out = {}
        for f in fields(self):
            t = getattr(self, f.name)
            if t is None:
                out[f.name] = None
                continue
            out[f.name] = t.to(*args, **kwargs) if t.is_floating_point() else t.to(device=t.device)
        return Calibration(**out)

    def to_dict(self) -> dict | list[dict]:
        """Plain JSON-able values: a dict for one image, a list of dicts for a batch."""
        if self.batched:
            return [self[i].to_dict() for i in range(len(self))]
        out = {}
        for f in fields(self):
            if getattr(self, f.name) is None:
                continue
            value = getattr(self, f.name).detach().cpu()
            out[f.name] = value.tolist() if value.dim() else value.item()
        out["height"], out["width"] = (int(v) for v in out.pop("image_size"))
        return out

    def __repr__(self) -> str:
        if self.batched:
            return f"Calibration(batch={len(self)})"
        return (
            f"Calibration(focal={float(self.focal):.1f}px, fov_v={float(self.fov_v):.1f}, "
            f"pitch={float(self.pitch):.2f}, roll={float(self.roll):.2f}, yaw={float(self.yaw):.2f}, "
            f"valid={bool(self.valid)})"
        )



def _index(value: Tensor | None, index: int) -> Tensor | None:
    return None if value is None else value[index]
