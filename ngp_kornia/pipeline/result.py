"""The calibration result: a typed, batched container of tensors with attribute access."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import ClassVar

import torch
from torch import Tensor

from ngp_kornia.geometry.pinhole import Camera
from ngp_kornia.pipeline import camera_export as cameras

__all__ = ["Calibration", "lens_from_dict"]


def _from_camera(name: str) -> property:
    """A read-only attribute of the calibration that is the camera's (:class:`~ngp_kornia.geometry.pinhole.Camera`)."""
    return property(lambda self: getattr(self.camera, name), doc=f"The camera's ``{name}`` (see the class docstring).")


def lens_from_dict(values: dict) -> Tensor | None:
    """The lens distortion (a () float64 tensor, :attr:`Calibration.k1`) of a calibration's :meth:`Calibration.to_dict`
    (or a rendered image's ground truth, which names it the same); None for a distortion-free pinhole."""
    return None if values.get("k1") is None else torch.tensor(float(values["k1"]), dtype=torch.float64)


@dataclass
class Calibration:
    """Camera calibration of one image or a batch (every field has a leading batch dim ``B`` when batched).

    Conventions: pixels x right, y down, origin at the centre of the top-left pixel, in the *input* image's
    pixels; camera frame x right, y down, z forward; ``R`` maps world directions to camera directions with world y
    pointing down; pitch > 0 looks up; roll > 0 when the scene's up direction leans right in the image; angles in
    degrees. See :mod:`ngp_kornia.geometry.camera`.

    The camera is held as its parameters (:class:`~ngp_kornia.geometry.pinhole.Camera`: focal length, principal
    point, ``k1``, rotation, image size); ``K``, ``R``, ``focal``, the fields of view, the angles, ``up``,
    ``zenith``, ``horizon``, ``vps``, ``image_size``, ``k1`` and ``principal_point`` are read from it (computed once,
    differentiable), the other attributes are the calibration's own. :data:`FIELDS` names them all.

    Attributes:
        camera: the :class:`~ngp_kornia.geometry.pinhole.Camera`, batched as the calibration; ``camera.to_kornia()``
            and ``camera.to_camera_model()`` give kornia's camera types.
        K: (B, 3, 3) intrinsics (principal point at the image centre unless it was given or estimated); with
            ``k1`` those of the undistorted image (the pinhole camera once the distortion is removed).
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
        valid: (B,) bool; False when the image offered no valid frame candidate, or when the orientation check
            finds no man-made structure in it (:mod:`ngp_kornia.pipeline.upright_check`); the result is then a
            level camera (pitch, roll and yaw 0) with the known focal length or a 60 degree field of view on the
            long side, at confidence 0.
        image_size: (B, 2) ``(height, width)`` in pixels.
        principal_point: (B, 2) ``(c_x, c_y)`` in pixels, ``K[:, :2, 2]``.
        exif_orientation: (B,) long: the EXIF orientation tag (1-8) of the file that was applied before
            calibrating, so every field is in the pixels of the image as displayed (6 and 8: a phone photo stored
            turned, ...); 1 when nothing was turned: files stored upright, and arrays and tensors, which are taken
            as they are.
        confidence: (B,) predicted probability, in [0, 1], that the horizon error is below 0.02 image heights
            (:mod:`ngp_kornia.pipeline.trust`); 0 where ``valid`` is False. None when not computed.
        pitch_std: (B,) standard deviation of the pitch, degrees (None when not computed).
        roll_std: (B,) standard deviation of the roll, degrees.
        fov_v_std: (B,) standard deviation of the vertical field of view, degrees (0 with a known focal length).
        principal_point_std: (B, 2) standard deviation of the principal point ``(c_x, c_y)`` in pixels where it
            was estimated (0 where given); None where it is the image centre.
        k1: (B,) radial distortion of the division model ``x_u = x_d / (1 + k1 |x_d|^2)``, ``x`` the ray
            coordinates ``(p - c) / f`` of a pixel ``p`` (``k1 < 0``: barrel); None for a distortion-free pinhole.
            With it, every other field is that of the undistorted image (:mod:`ngp_kornia.geometry.lens`).
        shared_photos: (B,) long: how many photos the intrinsics were estimated from jointly
            (the ``shared_intrinsics`` prior); None when each photo was calibrated alone.
        gravity: (B, 3) the gravity prior the calibration used: ``(pitch, roll, std)`` in degrees; None without.
        upright: (B,) probability that the image is the right way up and shows man-made structure (the
            orientation check, :mod:`ngp_kornia.pipeline.upright_check`); the confidence already includes it. None when
            not computed.
        turned: (B,) long: the image's most likely counter-clockwise turn from upright in degrees (0, 90, 180,
            270): ``np.rot90(image, -turned // 90)`` turns it back. The answer is always that of the image as
            given, upright or not: where the check is sure of the turn, the camera of the turned photo (its roll
            beyond 45 degrees, ``UprightSettings.turn_back``); elsewhere the camera whose up is the frame's axis
            nearest the image's vertical. None when not computed.
    """

    camera: Camera
    score: Tensor
    valid: Tensor
    exif_orientation: Tensor | None = None
    confidence: Tensor | None = None
    pitch_std: Tensor | None = None
    roll_std: Tensor | None = None
    fov_v_std: Tensor | None = None
    principal_point_std: Tensor | None = None
    shared_photos: Tensor | None = None
    gravity: Tensor | None = None
    upright: Tensor | None = None
    turned: Tensor | None = None

    #: every per-image value, in the order of :meth:`to_dict`: the camera's (parameters and derived geometry) and
    #: the calibration's own
    FIELDS: ClassVar[tuple[str, ...]] = (
        "K", "R", "focal", "fov_v", "fov_h", "pitch", "roll", "yaw", "up", "zenith", "horizon", "vps", "score",
        "valid", "image_size", "exif_orientation", "confidence", "pitch_std", "roll_std", "fov_v_std",
        "principal_point_std", "k1", "shared_photos", "gravity", "upright", "turned",
    )  # fmt: skip

    def __post_init__(self) -> None:
        if self.exif_orientation is None:  # made without it: nothing was turned
            self.exif_orientation = torch.ones_like(self.focal, dtype=torch.long)

    # --- the camera's values (Camera: parameters and what follows from them) ---

    K = _from_camera("K")
    R = _from_camera("R")
    focal = _from_camera("focal")
    fov_v = _from_camera("fov_v")
    fov_h = _from_camera("fov_h")
    pitch = _from_camera("pitch")
    roll = _from_camera("roll")
    yaw = _from_camera("yaw")
    up = _from_camera("up")
    zenith = _from_camera("zenith")
    horizon = _from_camera("horizon")
    vps = _from_camera("vps")
    image_size = _from_camera("image_size")
    k1 = _from_camera("lens")
    principal_point = _from_camera("center")

    @property
    def batched(self) -> bool:
        return self.camera.batched

    def __len__(self) -> int:
        if not self.batched:
            raise TypeError("an unbatched Calibration has no length")
        return len(self.camera)

    def __getitem__(self, index: int) -> Calibration:
        """The calibration of one image of a batch, without the batch dim."""
        if not self.batched:
            raise TypeError("an unbatched Calibration cannot be indexed")
        values = {name: _index(value, index) for name, value in self._own().items()}
        return Calibration(camera=self.camera[index], **values)

    def apply(self, fn: Callable[[Tensor], Tensor]) -> Calibration:
        """A calibration of ``fn`` applied to every tensor, the camera's parameters included (None stays None)."""
        values = {name: None if value is None else fn(value) for name, value in self._own().items()}
        return Calibration(camera=self.camera.apply(fn), **values)

    def to(self, *args, **kwargs) -> Calibration:
        """Move or cast like :meth:`torch.Tensor.to`: floating-point tensors take the dtype, all the device."""
        device = torch._C._nn._parse_to(*args, **kwargs)[0]
        return self.apply(lambda t: t.to(*args, **kwargs) if t.is_floating_point() else t.to(device or t.device))

    def clone(self) -> Calibration:
        """A copy with every tensor cloned, like :meth:`torch.Tensor.clone`."""
        return self.apply(torch.clone)

    def _own(self) -> dict[str, Tensor | None]:
        """The values besides the camera, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "camera"}

    def to_dict(self) -> dict | list[dict]:
        """Plain JSON-able values: a dict for one image, a list of dicts for a batch.

        The :data:`FIELDS` (those not None), but ``height`` and ``width`` for the image size; then the principal point
        ``cx``, ``cy`` (our pixels) and ``distortion``, OpenCV's ``(k1, k2, p1, p2, k3)``: all zero for a
        distortion-free pinhole, else the polynomial closest to the division model's ``k1`` over the image
        (:func:`~ngp_kornia.geometry.lens.opencv_radial`); with ``shared_photos``, ``shared`` names the intrinsics the
        photos share (``focal``, and ``principal_point`` and ``k1`` where modelled); ``gravity`` becomes
        ``{"pitch", "roll", "std"}``.
        """
        if self.batched:
            return [self[i].to_dict() for i in range(len(self))]
        out = {}
        for name in self.FIELDS:
            if getattr(self, name) is None:
                continue
            value = getattr(self, name).detach().cpu()
            out[name] = value.tolist() if value.dim() else value.item()
        out["height"], out["width"] = (int(v) for v in out.pop("image_size"))
        out.update(cameras.pinhole_keys(self.camera))  # cx, cy and OpenCV's distortion
        if self.shared_photos is not None:
            modelled = {"principal_point": self.principal_point_std, "k1": self.k1}
            out["shared"] = ["focal"] + [name for name, value in modelled.items() if value is not None]
        if self.gravity is not None:
            out["gravity"] = dict(zip(("pitch", "roll", "std"), out["gravity"], strict=True))
        return out

    def __repr__(self) -> str:
        if self.batched:
            return f"Calibration(batch={len(self)})"
        return (
            f"Calibration(focal={float(self.focal):.1f}px, fov_v={float(self.fov_v):.1f}, "
            f"pitch={float(self.pitch):.2f}, roll={float(self.roll):.2f}, yaw={float(self.yaw):.2f}, "
            f"valid={bool(self.valid)}"
            + (f", turned={int(self.turned)}" if self.turned is not None and int(self.turned) else "")
            + (f", confidence={float(self.confidence):.2f})" if self.confidence is not None else ")")
        )

    # --- the camera types of other tools (ngp_kornia.pipeline.camera_export) ---

    def to_kornia(self):
        """This calibration as a batched :class:`kornia.geometry.camera.PinholeCamera`.

        Intrinsics are ``K`` and extrinsics ``[R | 0]`` as (B, 4, 4) (B = 1 for an unbatched calibration), height
        and width are (B,). kornia shares our pixel convention (origin at the top-left pixel's centre), so
        ``to_kornia().project(X)`` for world points ``X`` (B, N, 3) gives the pixels ``K R X`` in the input image.

        Example:
            >>> import torch
            >>> from ngp_kornia import calibrate
            >>> camera = calibrate(torch.rand(3, 48, 64)).to_kornia()
            >>> camera.intrinsics.shape, camera.extrinsics.shape, camera.width.tolist()
            (torch.Size([1, 4, 4]), torch.Size([1, 4, 4]), [64.0])
        """
        return self.camera.to_kornia()

    def to_camera_model(self):
        """This calibration's intrinsics as kornia's :class:`~kornia.sensors.camera.CameraModel`: ``PINHOLE``
        without ``k1``, else ``BROWN_CONRADY`` with the radial polynomial closest to the division model over the
        image (:meth:`~ngp_kornia.geometry.pinhole.Camera.to_camera_model`). Its ``project`` takes camera-frame
        points to pixels of the photo.

        Example:
            >>> import torch
            >>> from ngp_kornia import calibrate
            >>> model = calibrate(torch.rand(3, 48, 64)).to_camera_model()
            >>> type(model._model).__name__, model.params[2:].tolist()
            ('PinholeModel', [31.5, 23.5])
        """
        return self.camera.to_camera_model()

    def to_opencv(self):
        """OpenCV's ``(K, dist)``: float64 numpy arrays, (3, 3) and (5,) (batched: (B, 3, 3) and (B, 5)); ``dist``
        is zero for a distortion-free pinhole, else OpenCV's polynomial closest to ``k1`` over the image.

        OpenCV shares our pixel convention (origin at the top-left pixel's centre), so ``K`` is used unchanged, e.g.
        ``cv2.projectPoints(X, cv2.Rodrigues(R)[0], np.zeros(3), K, dist)``.

        Example:
            >>> import torch
            >>> from ngp_kornia import calibrate
            >>> K, dist = calibrate(torch.rand(3, 48, 64)).to_opencv()
            >>> K.shape, K.dtype, dist.tolist()
            ((3, 3), dtype('float64'), [0.0, 0.0, 0.0, 0.0, 0.0])
        """
        return cameras.opencv_camera(self.camera)

    def to_colmap(self, model: str | None = None, camera_id: int = 1) -> dict | list[dict]:
        """COLMAP's camera: ``{"camera_id", "model", "width", "height", "params", "line"}``.

        COLMAP's pixel origin is the top-left *corner* of the image, ours the *centre* of the top-left pixel, so
        the principal point is written half a pixel larger: ``cx + 0.5``, ``cy + 0.5`` (a centred principal point
        is ``(W / 2, H / 2)`` there). ``line`` is the ``cameras.txt`` line ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``.

        Args:
            model: ``"SIMPLE_PINHOLE"`` (params ``f, cx, cy``), ``"PINHOLE"`` (``fx, fy, cx, cy``),
                ``"SIMPLE_RADIAL"`` (``f, cx, cy, k``) or ``"RADIAL"`` (``f, cx, cy, k1, k2``), the radial terms
                closest to ``k1``; None: ``SIMPLE_PINHOLE``, or ``RADIAL`` for a calibration with ``k1``.
            camera_id: the id of the camera (a batch numbers its cameras from it).

        Returns:
            a dict, or for a batch a list of dicts.

        Example:
            >>> import torch
            >>> from ngp_kornia import calibrate
            >>> camera = calibrate(torch.rand(3, 48, 64)).to_colmap()
            >>> camera["line"].split()[:4], camera["params"][1:]
            (['1', 'SIMPLE_PINHOLE', '64', '48'], [32.0, 24.0])
        """
        if self.batched:
            return [self[i].to_colmap(model, camera_id + i) for i in range(len(self))]
        return cameras.colmap_camera(self.camera, model, camera_id)


def _index(value: Tensor | None, index: int) -> Tensor | None:
    return None if value is None else value[index]
