"""Procedural renderer of man-made scenes with exact ground-truth calibration: the training data of the project and
its built-in demo.

:func:`render_scene` draws, from one integer seed, a photo-like image of a street crossing, a furnished room or an
Atlanta-world plaza seen by a random pinhole camera, and returns it with the camera's ground truth (intrinsics,
rotation, pitch / roll / yaw, field of view, zenith, horizon, Manhattan vanishing points), computed with the
functions of :mod:`ngp_kornia.geometry.camera` so it follows the project's conventions exactly:

* the principal point is the image centre ``((W - 1) / 2, (H - 1) / 2)`` unless
  :attr:`RenderConfig.centre_std` moves it (the label's ``K`` is always the true one), pixels have their
  origin at the centre of the top-left pixel, square pixels, no distortion;
* ``R = rotation_from_angles(pitch, roll, yaw)`` maps world to camera; the camera stands at the world origin and
  the ground is the plane ``y = camera_height`` (world y points down);
* ``vps[i] = K @ R[:, i]`` normalised: the vanishing points of the world axes, row 1 the vertical. Streets and
  rooms are aligned with the world axes; in Atlanta scenes the world axes are the frame of the dominant block group
  (the largest block, straight ahead of the camera), other groups are turned by ``frames`` degrees of yaw.

:func:`render_dataset` writes a folder of images plus ``ground_truth.json``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from ngp_kornia.geometry.camera import (
    focal_from_fov,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    rotation_from_angles,
    up_from_rotation,
    vanishing_points_from_rotation,
    zenith_from_up,
)
from ngp_kornia.training.synth.hard import Additions
from ngp_kornia.training.synth.interior import make_room
from ngp_kornia.training.synth.layouts import make_street
from ngp_kornia.training.synth.lighting import scene_lighting
from ngp_kornia.training.synth.objects import ObjectMap, draw_object_map
from ngp_kornia.training.synth.painter import Canvas, PinholeView
from ngp_kornia.training.synth.pixels import foliage_texture, ground_haze, photometric, sky_and_ground, view_rays
from ngp_kornia.training.synth.plaza import make_atlanta
from ngp_kornia.training.synth.render_config import KINDS, RenderConfig
from ngp_kornia.training.synth.scene import OBJECT_KINDS, Lighting, Scene, draw_ground, draw_objects

__all__ = [
    "RenderedScene",
    "camera_ground_truth",
    "render_dataset",
    "render_scene",
]


@dataclass
class RenderedScene:
    """A rendered image and its exact ground truth (torch float64; angles in degrees, lengths in pixels).

    Attributes:
        image: (H, W, 3) uint8 RGB.
        K: (3, 3) the true intrinsics (principal point at the image centre unless the config moves it).
        R: (3, 3) world-to-camera rotation.
        focal: focal length.
        fov_v: vertical field of view.
        fov_h: horizontal field of view.
        pitch: pitch.
        roll: roll.
        yaw: yaw (heading in the world frame).
        zenith: (3,) zenith VP ``K @ up`` in homogeneous pixels.
        horizon: (3,) horizon line, ``a^2 + b^2 = 1``, ``b >= 0``.
        vps: (3, 3) rows ``K @ R[:, i]`` normalised: the VPs of world x, y (vertical), z.
        seed: the seed it was rendered from.
        kind: ``street``, ``indoor`` or ``atlanta``.
        frames: yaws (degrees) of the block groups in the scene, the ground-truth one (0) first.
        scene: the 3D scene (for checks and debugging).
        k1: the radial distortion coefficient the image was warped with (0: a pinhole image).
        objects: what each pixel shows (:class:`~ngp_kornia.training.synth.objects.ObjectMap`), warped as the image
            is; None unless :func:`render_scene` was asked for it.
    """

    image: np.ndarray
    K: Tensor
    R: Tensor
    focal: Tensor
    fov_v: Tensor
    fov_h: Tensor
    pitch: Tensor
    roll: Tensor
    yaw: Tensor
    zenith: Tensor
    horizon: Tensor
    vps: Tensor
    seed: int
    kind: str
    frames: tuple[float, ...] = (0.0,)
    scene: Scene | None = field(default=None, repr=False)
    k1: float = 0.0
    objects: ObjectMap | None = field(default=None, repr=False)

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    def to_dict(self) -> dict:
        """The ground truth as plain JSON-able lists and floats.

        Keys: ``K, R, focal, fov_v, fov_h, pitch, roll, yaw, zenith, horizon, vps, width, height, seed, kind``,
        and ``k1`` when the image was distorted.
        """
        out = {name: getattr(self, name).tolist() for name in ("K", "R", "zenith", "horizon", "vps")}
        for name in ("focal", "fov_v", "fov_h", "pitch", "roll", "yaw"):
            out[name] = float(getattr(self, name))
        out.update(width=self.width, height=self.height, seed=int(self.seed), kind=self.kind)
        if self.k1 != 0.0:
            out["k1"] = float(self.k1)
        return out


def camera_ground_truth(fov_v: float, pitch: float, roll: float, yaw: float, size: tuple[int, int],
                        offset: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The calibration ground truth of a camera, with the project's geometry functions.

    Args:
        fov_v: vertical field of view (degrees).
        pitch: pitch (degrees).
        roll: roll (degrees).
        yaw: yaw (degrees).
        size: image ``(W, H)``.
        offset: the principal point's offset ``(dx, dy)`` from the image centre, pixels.

    Returns:
        A dict of float64 tensors: ``K, R, focal, fov_v, fov_h, pitch, roll, yaw, zenith, horizon, vps``.

    Example:
        >>> gt = camera_ground_truth(60.0, 0.0, 0.0, 0.0, (640, 480))
        >>> gt["horizon"].tolist()  # level camera: the horizon is the middle row
        [0.0, 1.0, -239.5]
    """
    W, H = size
    t = {k: torch.tensor([float(v)], dtype=torch.float64) for k, v in
         dict(fov_v=fov_v, pitch=pitch, roll=roll, yaw=yaw).items()}
    focal = focal_from_fov(t["fov_v"], H)
    center = image_center(H, W, like=focal)
    if offset[0] != 0.0 or offset[1] != 0.0:
        center = center + torch.tensor([float(offset[0]), float(offset[1])], dtype=center.dtype)
    K = intrinsics_matrix(focal, center)
    R = rotation_from_angles(t["pitch"], t["roll"], t["yaw"])
    zenith = zenith_from_up(K, up_from_rotation(R))
    return {
        "K": K[0], "R": R[0], "focal": focal[0], "fov_v": t["fov_v"][0], "fov_h": fov_from_focal(focal, W)[0],
        "pitch": t["pitch"][0], "roll": t["roll"][0], "yaw": t["yaw"][0], "zenith": zenith[0],
        "horizon": horizon_from_zenith(K, zenith)[0], "vps": vanishing_points_from_rotation(K, R)[0],
    }


def _check_size(size) -> tuple[int, int]:
    if len(size) != 2 or any(int(s) != s or s < 8 for s in size):
        raise ValueError(f"size must be (W, H) with integers >= 8, got {size}")
    return int(size[0]), int(size[1])


def _uniform(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def render_scene(seed: int, size: tuple[int, int] = (640, 480), config: RenderConfig | None = None,
                 objects: bool = False) -> RenderedScene:
    """Render one random scene with its exact calibration ground truth, deterministically from ``seed``.

    Args:
        seed: non-negative integer; the same seed, size and config always give the same image.
        size: image ``(W, H)``.
        config: what to draw; :class:`RenderConfig` defaults when None.
        objects: also draw the object map (what each pixel shows); the image is the same either way.

    Returns:
        The image and its ground truth.

    Example:
        >>> r = render_scene(3, (64, 48))
        >>> r.image.shape, r.image.dtype, tuple(r.K.shape), r.K[0, 2].item()
        ((48, 64, 3), dtype('uint8'), (3, 3), 31.5)
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    W, H = _check_size(size)
    cfg = RenderConfig() if config is None else config
    # the hard cases draw from a fourth stream, the camera imperfections from a fifth, the textures from a sixth: the
    # first three are those of spawn(3), as before they existed (a SeedSequence's i-th child does not depend on how
    # many are spawned)
    cam_rng, scene_rng, photo_rng, hard_rng, lens_rng, texture_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(6))
    names = [k for k in KINDS if cfg.kinds.get(k, 0.0) > 0]
    p = np.array([cfg.kinds[k] for k in names])
    kind = names[int(cam_rng.choice(len(names), p=p / p.sum()))]
    fov_v, pitch, roll, yaw = (_uniform(cam_rng, r) for r in (cfg.fov_v, cfg.pitch, cfg.roll, cfg.yaw))
    cam_h = _uniform(cam_rng, cfg.indoor_camera_height if kind == "indoor" else cfg.camera_height)
    if kind != "indoor" and cfg.fronto_prob > 0 and hard_rng.random() < cfg.fronto_prob:
        yaw = _fronto_yaw(hard_rng, kind, yaw, cfg.fronto_jitter)
    offset = (0.0, 0.0)
    if cfg.centre_std > 0:
        offset = tuple(float(v) for v in np.clip(lens_rng.normal(0.0, 1.0, 2), -3, 3) * cfg.centre_std * H)
    gt = camera_ground_truth(fov_v, pitch, roll, yaw, (W, H), offset)

    k1 = float(np.clip(lens_rng.normal(), -3, 3) * cfg.radial_distortion) if cfg.radial_distortion > 0 else 0.0
    if tuple(cfg.k1_range) != (0.0, 0.0):
        k1 = _uniform(lens_rng, cfg.k1_range)
    source = _undistorted_coordinates(gt["K"].numpy(), k1, W, H) if k1 != 0.0 else None
    margin = 0 if source is None else _margin(source, W, H)
    K = gt["K"].numpy() + np.array([[0, 0, margin], [0, 0, margin], [0, 0, 0]])
    view = PinholeView(K, gt["R"].numpy(), np.zeros(3), W + 2 * margin, H + 2 * margin)
    add = Additions(hard_rng, cfg.stairs, cfg.billboards) if cfg.stairs > 0 or cfg.billboards > 0 else None
    scene = _make_scene(kind, scene_rng, cam_h, cfg.clutter, view, yaw, add)
    image = _paint(view, scene, *scene_lighting(photo_rng, kind, cfg), cfg.antialias)
    object_map = _objects_and_foliage(view, scene, image, cfg, texture_rng, objects)
    if source is not None:
        image = cv2.remap(image, *(source + margin), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if object_map is not None:  # nearest: ids are labels, never blended
            ids = cv2.remap(object_map.ids, *(source + margin), cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
            object_map = ObjectMap(ids, object_map.kinds)
    if cfg.photometric:
        image = photometric(photo_rng, image, cfg)
    return RenderedScene(image=image, seed=int(seed), kind=kind, frames=tuple(scene.frames), scene=scene, k1=k1,
                         objects=object_map, **gt)


def _make_scene(kind: str, rng: np.random.Generator, cam_h: float, clutter: float, view: PinholeView, yaw: float,
                add: Additions | None) -> Scene:
    if kind == "street":
        return make_street(rng, cam_h, clutter, view=view, additions=add)
    if kind == "indoor":
        return make_room(rng, cam_h, clutter, view_yaw=yaw)
    return make_atlanta(rng, cam_h, clutter, view_yaw=yaw, additions=add)


def _objects_and_foliage(view: PinholeView, scene: Scene, image: np.ndarray, cfg: RenderConfig,
                         rng: np.random.Generator, objects: bool) -> ObjectMap | None:
    """The object map when asked for, and the leafy texture (drawn on the map's leaf pixels) when the config asks."""
    if not objects and cfg.foliage <= 0:
        return None
    object_map = draw_object_map(view, scene)
    if cfg.foliage > 0:
        leaves = np.isin(object_map.kind_map(), [OBJECT_KINDS.index(k) for k in ("tree", "bush", "plant")])
        foliage_texture(rng, image, leaves, cfg.foliage * float(rng.uniform(0.5, 1.0)))
    return object_map if objects else None


def _paint(view: PinholeView, scene: Scene, light: Lighting, sky: tuple, antialias: bool) -> np.ndarray:
    """The pinhole image of a scene: sky, ground, haze and objects."""
    if scene.ground_color is None:  # indoors: the room hides everything, only seams between faces may show
        image = np.full((view.height, view.width, 3), 150, np.uint8)
    else:
        sin_down = view_rays(view)
        ground = scene.ground_color * light.factor(np.array([0.0, -1.0, 0.0]))
        image = sky_and_ground(view, ground, sky, sin_down)
    canvas = Canvas(view, image, antialias=antialias)
    draw_ground(canvas, scene, light)
    if scene.ground_color is not None:
        ground_haze(image, scene.ground_y, light.visibility, light.haze, sin_down)
    draw_objects(canvas, scene, light)
    return image


def _undistorted_coordinates(K: np.ndarray, k1: float, W: int, H: int) -> np.ndarray:
    """(2, H, W) float32: for every pixel of the distorted image, where its ray meets the pinhole image (the
    division model ``x_u = x_d / (1 + k1 |x_d|^2)``)."""
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    xd = (np.arange(W, dtype=np.float64)[None, :] - cx) / f + np.zeros((H, 1))
    yd = (np.arange(H, dtype=np.float64)[:, None] - cy) / f + np.zeros((1, W))
    scale = 1.0 + k1 * (xd * xd + yd * yd)
    return np.stack([xd / scale * f + cx, yd / scale * f + cy]).astype(np.float32)


def _margin(source: np.ndarray, W: int, H: int) -> int:
    """Pixels to draw beyond each border so that every source coordinate lies inside the pinhole image."""
    over = max(-source.min(), source[0].max() - (W - 1), source[1].max() - (H - 1), 0.0)
    return int(math.ceil(over)) + 2


def _fronto_yaw(rng: np.random.Generator, kind: str, yaw: float, jitter: float) -> float:
    """A yaw facing a facade square on: on a street the facades along the main road (normals along world x), in a
    plaza the dominant block's nearest side; plus Gaussian jitter."""
    step = 180.0 if kind == "street" else 90.0
    base = 90.0 + step * round((yaw - 90.0) / step)
    return float(base + rng.normal(0.0, jitter))


def render_dataset(outdir: str | Path, count: int, seed: int = 0, size: tuple[int, int] = (640, 480),
                   config: RenderConfig | None = None, ext: str = "png",
                   progress: Callable[[int], object] | None = None) -> list[dict]:
    """Render ``count`` scenes into ``outdir`` as ``000000.png``... plus ``ground_truth.json``.

    Image ``i`` is rendered from its own seed, derived from ``(seed, i)``, so datasets of different seeds do not
    overlap and a prefix of a dataset does not depend on ``count``; each record stores its seed, so
    ``render_scene(record["seed"], size, config)`` re-renders it.

    Args:
        outdir: output folder (created).
        count: number of images.
        seed: dataset seed.
        size: image ``(W, H)``.
        config: render settings.
        ext: ``png`` (lossless) or ``jpg``.
        progress: called with 1 after each image is written (e.g. a progress bar's ``update``).

    Returns:
        The records written to ``ground_truth.json``: :meth:`RenderedScene.to_dict` plus ``image`` (file name).
    """
    if count < 0 or seed < 0:
        raise ValueError(f"count and seed must be non-negative, got {count} and {seed}")
    if ext not in ("png", "jpg"):
        raise ValueError(f"ext must be 'png' or 'jpg', got {ext!r}")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for i in range(count):
        s = int(np.random.SeedSequence([int(seed), i]).generate_state(1)[0] >> 1)
        r = render_scene(s, size, config)
        name = f"{i:06d}.{ext}"
        if not cv2.imwrite(str(out / name), r.image[..., ::-1]):
            raise OSError(f"could not write {out / name}")
        records.append({"image": name, **r.to_dict()})
        if progress is not None:
            progress(1)
    (out / "ground_truth.json").write_text(json.dumps(records, indent=1))
    return records
