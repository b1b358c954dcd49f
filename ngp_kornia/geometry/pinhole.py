r"""The camera object: a batch of calibrated cameras held as their parameters, on kornia's camera types.

A :class:`Camera` holds what a calibration finds, per image: the intrinsics as kornia's
:class:`~kornia.sensors.camera.PinholeModel` parameters ``(f_x, f_y, c_x, c_y)`` (this package's cameras have square
pixels, ``f_x = f_y``; ``(c_x, c_y)`` the centre, the principal point), the lens: the division model's coefficient
(:mod:`~ngp_kornia.geometry.lens`; None for a distortion-free pinhole), the world-to-camera rotation ``R`` and the image
size. Everything else is derived from them, as a property:
``K`` (kornia's ``PinholeModel.matrix()``), the fields of view, the up vector, zenith, horizon, the Manhattan
vanishing points and pitch / roll / yaw, in the conventions of :mod:`ngp_kornia.geometry.camera`. The properties
are differentiable with respect to the parameters and keep their device and dtype; each is computed once.

Each parameter is a per-image tensor (a leading batch dim ``B``, or none for one camera), so a batch may mix
cameras, e.g. cameras made from per-image priors. kornia's types come out of :meth:`Camera.to_kornia`
(:class:`~kornia.geometry.camera.PinholeCamera`), :meth:`Camera.to_camera_model`
(:class:`~kornia.sensors.camera.CameraModel`), :attr:`Camera.intrinsics` (``PinholeModel``) and
:attr:`Camera.rotation` (:class:`~kornia.geometry.liegroup.So3`).

Ours, around kornia's: kornia's camera types carry no rotation-derived horizon, zenith or vanishing points, and no
division-model distortion.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from kornia.core.check import KORNIA_CHECK_SHAPE
from kornia.core.exceptions import ShapeError
from kornia.geometry.camera import PinholeCamera
from kornia.geometry.conversions import Rt_to_matrix4x4, convert_affinematrix_to_homography3d
from kornia.geometry.liegroup import So3
from kornia.image import ImageSize
from kornia.sensors.camera import CameraModel, CameraModelType, PinholeModel
from torch import Tensor

from ngp_kornia.geometry.camera import (
    angles_from_rotation,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    normalize,
    pinhole_model,
    rotation_from_angles,
    up_from_rotation,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.geometry.lens import distort_points, opencv_radial, undistort_points

__all__ = ["Camera"]

#: the properties derived from the parameters (computed once, on first use)
DERIVED = ("K", "fov_v", "fov_h", "up", "zenith", "horizon", "vps", "pitch", "roll", "yaw")


#: dtypes whose derived values are computed in float32 (torch has no half-precision solve), then cast back
_HALF = (torch.float16, torch.bfloat16)


def _derived(compute: Callable[[Camera], Tensor]) -> property:
    """A property computed once from the camera's parameters and kept; not kept where it was computed without
    autograd from parameters that require grad (``torch.no_grad()`` inside a stage), so a later use outside has its
    gradient."""
    name = compute.__name__

    def get(self: Camera) -> Tensor:
        if name in self.__dict__:
            return self.__dict__[name]
        if self._params.dtype in _HALF:
            lens = None if self._lens is None else self._lens.float()
            single = Camera(self._params.float(), self._R.float(), self._image_size, lens)
            value = getattr(single, name).to(self._params.dtype)
        else:
            value = compute(self)
        if self._keeps():
            self.__dict__[name] = value
        return value

    return property(get, doc=compute.__doc__)


class Camera:
    """A batch of cameras: intrinsics, distortion and rotation as parameters; ``K``, fields of view, horizon and the
    other geometry derived from them (module docstring).

    Args:
        params: (B, 4) or (4,) kornia's ``PinholeModel`` parameters ``(f_x, f_y, c_x, c_y)`` in pixels.
        R: (B, 3, 3) or (3, 3) world-to-camera rotations (world y pointing down).
        image_size: (B, 2) or (2,) ``(height, width)`` in pixels.
        lens: (B,) or () the division model's coefficient, or None for a distortion-free pinhole.

    Example:
        >>> camera = Camera.from_angles(torch.tensor([500.0]), torch.tensor([10.0]), torch.tensor([-5.0]),
        ...                             image_size=(480, 640))
        >>> camera.K[0, 0].tolist(), round(float(camera.pitch), 4), round(float(camera.fov_h), 2)
        ([500.0, 0.0, 319.5], 10.0, 65.24)
        >>> camera.to_kornia().intrinsics.shape, camera.to_camera_model().params.shape
        (torch.Size([1, 4, 4]), torch.Size([1, 4]))
    """

    def __init__(self, params: Tensor, R: Tensor, image_size: Tensor, lens: Tensor | None = None) -> None:
        KORNIA_CHECK_SHAPE(params, ["*", "4"])
        KORNIA_CHECK_SHAPE(R, ["*", "3", "3"])
        KORNIA_CHECK_SHAPE(image_size, ["*", "2"])
        batch = params.shape[:-1]
        if len(batch) > 1 or R.shape[:-2] != batch or image_size.shape[:-1] != batch:
            raise ShapeError(
                f"params (B, 4), R (B, 3, 3) and image_size (B, 2) must share one batch dim (or none), got "
                f"{tuple(params.shape)}, {tuple(R.shape)} and {tuple(image_size.shape)}"
            )
        if lens is not None and lens.shape != batch:
            raise ShapeError(f"lens must be of shape {tuple(batch)} like the other parameters, got {tuple(lens.shape)}")
        self._params, self._R, self._image_size, self._lens = params, R, image_size, lens

    # --- constructors ---

    @classmethod
    def from_matrix(cls, K: Tensor, R: Tensor, image_size: Tensor, lens: Tensor | None = None) -> Camera:
        """The camera of intrinsics ``K`` (B, 3, 3) (no skew; its focal lengths and principal point are read),
        rotations ``R`` (B, 3, 3) and image sizes (B, 2) ``(height, width)``, or unbatched."""
        KORNIA_CHECK_SHAPE(K, ["*", "3", "3"])
        params = torch.stack([K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]], -1)
        return cls(params, R, torch.as_tensor(image_size, device=K.device).expand(*K.shape[:-2], 2), lens)

    @classmethod
    def from_angles(
        cls,
        focal: Tensor,
        pitch: Tensor,
        roll: Tensor,
        yaw: Tensor | None = None,
        *,
        image_size: tuple[int, int] | Tensor,
        center: Tensor | None = None,
        lens: Tensor | None = None,
    ) -> Camera:
        """A camera of focal length (B,) pixels and pitch / roll / yaw (B,) degrees (yaw 0 when omitted), in images of
        ``image_size`` ``(height, width)``, one for all or (B, 2); the principal point ``center`` (B, 2) or (2,) is the
        image centre when omitted."""
        KORNIA_CHECK_SHAPE(focal, ["B"])
        size = torch.as_tensor(image_size, device=focal.device).expand(len(focal), 2)
        if center is None:
            center = torch.stack([image_center(int(h), int(w), like=focal) for h, w in size.tolist()])
        point = center.to(focal).expand(len(focal), 2)
        params = torch.stack([focal, focal, point[:, 0], point[:, 1]], -1)
        yaw = None if yaw is None else yaw.to(focal)
        return cls(params, rotation_from_angles(pitch.to(focal), roll.to(focal), yaw), size, lens)

    # --- parameters ---

    @property
    def params(self) -> Tensor:
        """(B, 4) ``(f_x, f_y, c_x, c_y)`` in pixels, kornia's ``PinholeModel`` parameters."""
        return self._params

    @property
    def focal(self) -> Tensor:
        """(B,) focal length in pixels (``f_x``; square pixels)."""
        return self._params[..., 0]

    @property
    def center(self) -> Tensor:
        """(B, 2) the principal point ``(c_x, c_y)`` in pixels."""
        return self._params[..., 2:]

    @property
    def lens(self) -> Tensor | None:
        """(B,) the lens distortion, the division model's coefficient (:mod:`~ngp_kornia.geometry.lens`), None for a
        pinhole."""
        return self._lens

    @property
    def R(self) -> Tensor:
        """(B, 3, 3) world-to-camera rotations."""
        return self._R

    @property
    def image_size(self) -> Tensor:
        """(B, 2) ``(height, width)`` in pixels."""
        return self._image_size

    @property
    def distorted(self) -> bool:
        """Whether the lens has a distortion (:attr:`lens` is set)."""
        return self._lens is not None

    def undistort(self, points: Tensor) -> Tensor:
        """Pixels (B, N, 2) of the photos as taken -> those of the undistorted images (:mod:`~ngp_kornia.geometry.lens`,
        in the points' dtype); as they are for a pinhole."""
        if self._lens is None:
            return points
        return undistort_points(points, self.K.to(points), self._lens.to(points))

    def distort(self, points: Tensor) -> Tensor:
        """Pixels (B, N, 2) of the undistorted images -> those of the photos as taken (the inverse of
        :meth:`undistort`)."""
        if self._lens is None:
            return points
        return distort_points(points, self.K.to(points), self._lens.to(points))

    def with_matrix(self, K: Tensor, R: Tensor) -> Camera:
        """The camera of intrinsics ``K`` and rotations ``R`` in place of its own, its image size and lens kept."""
        return Camera.from_matrix(K, R, self._image_size, self._lens)

    # --- kornia's types ---

    @property
    def intrinsics(self) -> PinholeModel:
        """kornia's :class:`~kornia.sensors.camera.PinholeModel` of these intrinsics (the undistorted camera)."""
        return pinhole_model(self._params, self._kornia_size())

    @property
    def rotation(self) -> So3:
        """The rotations as kornia's :class:`~kornia.geometry.liegroup.So3`."""
        return So3.from_matrix(self._R)

    def to_kornia(self) -> PinholeCamera:
        """A batched :class:`kornia.geometry.camera.PinholeCamera`: intrinsics ``K`` and extrinsics ``[R | 0]`` as
        (B, 4, 4) (B = 1 for one camera), height and width (B,), in ``K``'s dtype and device.

        The camera sits at the world origin (one photo says nothing of where); kornia shares this package's pixel
        convention (origin at the top-left pixel's centre), so ``to_kornia().project(X)`` for world points ``X``
        (B, N, 3) gives the pixels ``K R X`` (of the undistorted image when :attr:`lens` is set).
        """
        K, R = self.K.reshape(-1, 3, 3), self._R.reshape(-1, 3, 3).to(self.K)
        intrinsics = convert_affinematrix_to_homography3d(torch.nn.functional.pad(K, (0, 1)))  # [K | 0] -> 4x4
        extrinsics = Rt_to_matrix4x4(R, torch.zeros_like(R[..., :1]))
        size = self._image_size.reshape(-1, 2).to(K)
        return PinholeCamera(intrinsics, extrinsics, size[:, 0].clone(), size[:, 1].clone())

    def to_camera_model(self) -> CameraModel:
        """kornia's :class:`~kornia.sensors.camera.CameraModel`: ``PINHOLE`` for a distortion-free camera, else
        ``BROWN_CONRADY`` with OpenCV's radial polynomial closest to the division model over the image
        (:meth:`radial_polynomial`), no tangential terms.

        Its ``project`` takes camera-frame points (``Vector3``) to pixels of the photo as taken (distorted).
        """
        size = self._kornia_size()
        if self._lens is None:
            return CameraModel(size, CameraModelType.PINHOLE, self._params)
        params = self._params.reshape(-1, 4)
        radial = self.radial_polynomial().reshape(-1, 3).to(params)  # (B, 3)
        zero = torch.zeros_like(radial[:, :1])
        coefficients = [radial[:, :2], zero, zero, radial[:, 2:], zero, zero, zero]  # radial 1-2, tangential, ...
        full = torch.cat([params, *coefficients], -1).reshape(*self._params.shape[:-1], 12)
        return CameraModel(size, CameraModelType.BROWN_CONRADY, full)

    def radial_polynomial(self, terms: int = 3) -> Tensor:
        """OpenCV's radial coefficients (the first ``terms`` of its three) closest to the lens over each image
        (:func:`~ngp_kornia.geometry.lens.opencv_radial`; float64, computed without gradient).

        Returns:
            (B, terms), or (terms,) for one camera; zero for a distortion-free pinhole.

        Example:
            >>> level = torch.zeros(1)
            >>> camera = Camera.from_angles(torch.tensor([500.0]), level, level, image_size=(480, 640))
            >>> camera.radial_polynomial().tolist(), camera.replace(lens=torch.tensor([-0.1])).radial_polynomial(1)
            ([[0.0, 0.0, 0.0]], tensor([[-0.0900]], dtype=torch.float64))
        """
        K, size = self.K.detach().reshape(-1, 3, 3), self._image_size.reshape(-1, 2)
        if self._lens is None:
            return torch.zeros(*self._params.shape[:-1], terms, dtype=torch.float64, device=K.device)
        lens = self._lens.reshape(-1)
        if bool((size == size[:1]).all()):  # one image size: the batch in one fit
            radial = opencv_radial(lens, K, int(size[0, 0]), int(size[0, 1]), terms)
        else:
            rows = range(len(K))
            radial = torch.cat([opencv_radial(lens[i, None], K[i, None], *map(int, size[i]), terms) for i in rows])
        return radial.reshape(*self._params.shape[:-1], terms)

    def _kornia_size(self) -> ImageSize:
        return ImageSize(self._image_size[..., 0], self._image_size[..., 1])

    # --- derived ---

    @_derived
    def K(self) -> Tensor:
        """(B, 3, 3) intrinsics ``[[f_x, 0, c_x], [0, f_y, c_y], [0, 0, 1]]`` (kornia's ``PinholeModel.matrix()``)."""
        return self.intrinsics.matrix()

    @_derived
    def fov_v(self) -> Tensor:
        """(B,) vertical field of view, degrees."""
        return self._fovs[..., 0]

    @_derived
    def fov_h(self) -> Tensor:
        """(B,) horizontal field of view, degrees."""
        return self._fovs[..., 1]

    @_derived
    def _fovs(self) -> Tensor:
        return fov_from_focal(self.focal[..., None], self._image_size)  # both sides at once, the same values

    @_derived
    def up(self) -> Tensor:
        """(B, 3) unit up vector in camera coordinates, ``-R[:, :, 1]``."""
        return up_from_rotation(self._R)

    @_derived
    def zenith(self) -> Tensor:
        """(B, 3) homogeneous zenith VP ``K @ up`` in pixels, unit norm (third coordinate 0 when at infinity)."""
        return normalize(zenith_from_up(self.K, self.up))

    @_derived
    def horizon(self) -> Tensor:
        """(B, 3) horizon line ``(a, b, c)`` in pixels, ``a^2 + b^2 = 1``, ``b >= 0``."""
        return horizon_from_zenith(self.K, self.zenith)

    @_derived
    def vps(self) -> Tensor:
        """(B, 3, 3) the three Manhattan VPs, homogeneous pixels, unit norm; row ``i`` is world axis ``i``'s."""
        return vanishing_points_from_rotation(self.K, self._R)

    @_derived
    def _angles(self) -> tuple[Tensor, Tensor, Tensor]:
        return angles_from_rotation(self._R)

    @_derived
    def pitch(self) -> Tensor:
        """(B,) degrees, > 0 looking up."""
        return self._angles[0]

    @_derived
    def roll(self) -> Tensor:
        """(B,) degrees, > 0 when the scene's up leans right in the image."""
        return self._angles[1]

    @_derived
    def yaw(self) -> Tensor:
        """(B,) degrees, relative to world z."""
        return self._angles[2]

    # --- a batch of tensors ---

    @property
    def batched(self) -> bool:
        return self._params.dim() == 2

    def __len__(self) -> int:
        if not self.batched:
            raise TypeError("an unbatched Camera has no length")
        return self._params.shape[0]

    def __getitem__(self, index) -> Camera:
        """The cameras ``index`` of a batch (an int drops the batch dim); the derived values are those of the batch,
        indexed."""
        if not self.batched:
            raise TypeError("an unbatched Camera cannot be indexed")
        return self.apply(lambda t: t[index])

    def _keeps(self) -> bool:
        """Whether derived values may be kept: autograd is on, or no parameter requires grad."""
        tensors = (self._params, self._R) if self._lens is None else (self._params, self._R, self._lens)
        return torch.is_grad_enabled() or not any(t.requires_grad for t in tensors)

    def apply(self, fn: Callable[[Tensor], Tensor]) -> Camera:
        """A camera of ``fn`` applied to every parameter tensor (``params``, ``R``, ``image_size``, ``lens``): a map
        of the batch's layout, device or dtype (index, stack, move, cast, clone), which is applied to the derived
        values too, so they stay those of the camera they came from (a batch's, indexed; float32's, cast)."""
        lens = None if self._lens is None else fn(self._lens)
        out = Camera(fn(self._params), fn(self._R), fn(self._image_size), lens)
        if self._keeps():
            for name in DERIVED:  # computed here, as one call computes them, then mapped
                out.__dict__[name] = fn(getattr(self, name))
        return out

    def to(self, *args, **kwargs) -> Camera:
        """Move or cast like :meth:`torch.Tensor.to`: floating-point parameters take the dtype, all the device."""
        device = torch._C._nn._parse_to(*args, **kwargs)[0]
        return self.apply(lambda t: t.to(*args, **kwargs) if t.is_floating_point() else t.to(device or t.device))

    def clone(self) -> Camera:
        """A copy with every parameter cloned."""
        return self.apply(torch.clone)

    def replace(self, **changes: Tensor | None) -> Camera:
        """A camera with some parameters replaced: ``params``, ``R``, ``image_size``, ``lens``.

        Example:
            >>> level = torch.zeros(1)
            >>> camera = Camera.from_angles(torch.tensor([500.0]), level, level, image_size=(480, 640))
            >>> camera.replace(lens=torch.tensor([-0.1])).to_camera_model().params.shape
            torch.Size([1, 12])
        """
        values = {"params": self._params, "R": self._R, "image_size": self._image_size, "lens": self._lens}
        unknown = set(changes) - set(values)
        if unknown:
            raise TypeError(f"Camera.replace() got unknown parameters {sorted(unknown)}; it takes {sorted(values)}")
        return Camera(**{**values, **changes})

    def __repr__(self) -> str:
        if self.batched:
            return f"Camera(batch={len(self)})"
        point = [round(v, 1) for v in self.center.tolist()]
        return (
            f"Camera(focal={float(self.focal):.1f}px, center={point}"
            f", pitch={float(self.pitch):.2f}, roll={float(self.roll):.2f}, yaw={float(self.yaw):.2f}"
            + ("" if self._lens is None else f", lens={float(self._lens):.4f}")
            + ")"
        )

