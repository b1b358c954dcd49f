"""Handing calibrations on to COLMAP: each photo's camera and a gravity prior, written into a COLMAP database (the
``colmap`` extra: ``pip install 'ngp-kornia[colmap]'``, pycolmap 4).

What is written, per photo (matched to the database's images by name: its path relative to COLMAP's image folder,
as ``ngp predict`` names them relative to its folder):

- **a camera** with ``prior_focal_length`` set, the model :meth:`Calibration.to_colmap` chooses (``SIMPLE_PINHOLE``,
  ``RADIAL`` for a lens with a distortion) or ``model=``;
- **a pose prior's gravity**: the direction of gravity in the camera frame (x right, y down, z forward, as ours), so
  ``(0, 1, 0)`` for a level camera; ``-up`` of the calibration (:func:`gravity_in_camera`). COLMAP's rotation
  averaging, gravity refinement and ``compute_rot90_from_gravity`` read it.

COLMAP reads the pixels as the file stores them, never turned by an EXIF orientation tag, whereas a calibration is
of the image as displayed: a photo with a tag is written in the stored pixels (its size, principal point and
gravity turned back, :func:`displayed_to_stored`), as COLMAP's own reader does with the tag's coarse gravity.

What is touched, and what never is:

- an image not in the database is added, with its own camera, rig and frame (as COLMAP's image reader adds them);
- an image already there keeps its ``image_id`` and camera id. Its camera is updated in place only where every image
  using it is being written and all of them give it the same camera (a camera per photo, as COLMAP makes them, or
  one shared camera with ``ngp predict --same-camera``); a camera shared with other images, or that the photos'
  calibrations disagree on, is left as it is (``camera_kept`` in the report says why) and only the gravity is written;
- an image whose camera in the database is of another size is left alone (``skipped``): another or a resized file;
- of an existing pose prior only ``gravity`` changes: a position (GPS), its covariance and coordinate system stay;
- keypoints, descriptors, matches, two-view geometries, other images, cameras, rigs and frames are never touched;
- photos without a valid calibration (``valid`` false, an error row) are skipped; what an earlier run wrote for them
  stays. Running it again updates what it wrote; nothing is duplicated. Every check comes before the first write,
  so bad input changes nothing.

Example:
    >>> import torch, pycolmap
    >>> from ngp_kornia import calibrate
    >>> from ngp_kornia.colmap import write_colmap_database
    >>> cal = calibrate(torch.rand(3, 48, 64))  # noise: not a valid calibration, so not written
    >>> report = write_colmap_database(getfixture("tmp_path") / "db.db", {"noise.png": cal})
    >>> report.skipped
    {'noise.png': 'no valid calibration (valid is false)'}
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
import torch

try:  # an optional dependency: the rest of the package runs without it
    import pycolmap
except ImportError as err:
    raise ImportError(f"the COLMAP hand-off needs pycolmap ({err}); install it with: pip install 'ngp-kornia[colmap]'"
                      ) from err

from ngp_kornia.errors import InputError
from ngp_kornia.geometry.pinhole import Camera
from ngp_kornia.io import apply_orientation
from ngp_kornia.pipeline import Calibration
from ngp_kornia.pipeline.camera_export import colmap_camera
from ngp_kornia.pipeline.result import lens_from_dict
from ngp_kornia.preflight import check_database

__all__ = [
    "ColmapReport",
    "displayed_to_stored",
    "gravity_in_camera",
    "read_predictions",
    "write_colmap_database",
]

#: relative tolerance within which the photos of one shared camera give it the same parameters
SAME_CAMERA_RTOL = 1e-6


@dataclass
class ColmapReport:
    """What :func:`write_colmap_database` did, by image name.

    Attributes:
        added: images added to the database (each with its camera and gravity prior).
        updated: images already there whose camera (unless in ``camera_kept``) and gravity were written.
        camera_kept: images whose camera was left as it is (the reason; their gravity was written).
        skipped: images left alone (the reason: no valid calibration, another image size).
    """

    added: list[str] = field(default_factory=list)
    updated: list[str] = field(default_factory=list)
    camera_kept: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: counts of images added, updated, skipped."""
        kept = f" ({len(self.camera_kept)} kept the camera they share)" if self.camera_kept else ""
        return (f"{len(self.added)} images added, {len(self.updated)} updated{kept}, "
                f"{len(self.skipped)} skipped")


@dataclass
class _Photo:
    """One photo as COLMAP gets it: its camera (no id yet) and gravity, both in the file's stored pixels."""

    name: str
    camera: pycolmap.Camera
    gravity: np.ndarray


def displayed_to_stored(orientation: int, height: int, width: int) -> np.ndarray:
    """The affine map (3, 3) from the pixels of an image as displayed to those of its file as stored, for an EXIF
    orientation tag (1-8; :func:`ngp_kornia.io.apply_orientation` turns stored into displayed).

    Args:
        orientation: the EXIF orientation tag.
        height, width: the displayed image's size.

    Returns:
        ``A`` with ``[x_s, y_s, 1] = A @ [x_d, y_d, 1]`` (pixel centres, origin at the top-left pixel's centre); its
        top-left (2, 2) block is a signed permutation: the same map turns directions in the camera frame.

    Example:
        >>> displayed_to_stored(6, 40, 30).astype(int).tolist()  # turned clockwise to display: x_s = y_d
        [[0, 1, 0], [-1, 0, 29], [0, 0, 1]]
    """
    probe = np.arange(6).reshape(2, 3)  # stored pixel (x, y) holds y * 3 + x
    shown = apply_orientation(probe, orientation)

    def stored(x: int, y: int) -> np.ndarray:
        return np.array(divmod(int(shown[y, x]), 3)[::-1], dtype=np.float64)

    origin = stored(0, 0)
    turn = np.stack([stored(1, 0) - origin, stored(0, 1) - origin], axis=1)
    stored_size = np.abs(turn) @ np.array([width, height], dtype=np.float64)  # (width, height) as stored
    corner = np.where(origin > 0, stored_size - 1.0, 0.0)  # where displayed (0, 0) lies in the stored pixels
    out = np.eye(3)
    out[:2, :2], out[:2, 2] = turn, corner
    return out


def gravity_in_camera(up) -> np.ndarray:
    """The direction of gravity in the camera frame (x right, y down, z forward): ``-up``, unit length, float64.

    Args:
        up: (3,) the up vector in camera coordinates (``Calibration.up``), any length.

    Returns:
        (3,) float64 unit vector, COLMAP's ``PosePrior.gravity`` for a file stored as displayed.

    Example:
        >>> gravity_in_camera([0.0, -1.0, 0.0]).tolist()  # a level camera: gravity along +y, down in the image
        [0.0, 1.0, 0.0]
    """
    down = -np.asarray(up, dtype=np.float64).reshape(3)
    return down / np.linalg.norm(down)


def _row(name: str, calibration: Calibration | Mapping) -> dict:
    """A calibration as a row of ``ngp predict`` (:meth:`Calibration.to_dict`), checked."""
    if not isinstance(name, str) or not name or PurePosixPath(name).is_absolute() or "\\" in name:
        raise InputError(f"image name {name!r}: give its path relative to COLMAP's image folder, with / between "
                         "folders (as ngp predict names it)")
    if isinstance(calibration, Calibration):
        if calibration.batched:
            raise InputError(f"{name}: a batched Calibration; give one image's, e.g. calibration[0]")
        return calibration.to_dict()
    if not isinstance(calibration, Mapping):
        raise InputError(f"{name}: a {type(calibration).__name__}; give a Calibration or a row of ngp predict")
    missing = [key for key in ("K", "up", "height", "width", "valid") if key not in calibration]
    if missing and "error" not in calibration:
        raise InputError(f"{name}: the row lacks {', '.join(missing)}; give a row as ngp predict writes it")
    return dict(calibration)


def _photo(name: str, row: dict, model: str | None) -> _Photo | str:
    """The photo COLMAP gets from a row, or why it gets none."""
    if "error" in row:
        return f"no calibration ({row['error']})"
    if not row["valid"]:
        return "no valid calibration (valid is false)"
    K, up = np.asarray(row["K"], dtype=np.float64), np.asarray(row["up"], dtype=np.float64)
    if K.shape != (3, 3) or up.shape != (3,) or not (np.isfinite(K).all() and np.isfinite(up).all()):
        return "no finite camera in the row"
    height, width = int(row["height"]), int(row["width"])
    to_stored = displayed_to_stored(int(row.get("exif_orientation", 1)), height, width)
    turn = np.eye(3)
    turn[:2, :2] = to_stored[:2, :2]
    K_stored = to_stored @ K @ turn.T  # pixels and camera directions, both turned to the file's stored frame
    size = (width, height) if turn[0, 1] else (height, width)
    stored = Camera.from_matrix(torch.from_numpy(K_stored), torch.eye(3, dtype=torch.float64), torch.tensor(size),
                                lens_from_dict(row))
    exported = colmap_camera(stored, model)
    camera = pycolmap.Camera(model=exported["model"], width=exported["width"], height=exported["height"],
                             params=exported["params"], has_prior_focal_length=True)
    return _Photo(name, camera, turn @ gravity_in_camera(up))


def read_predictions(path: str | Path) -> dict[str, dict]:
    """The rows of an ``ngp predict`` results file by image name (error rows included: :func:`write_colmap_database`
    skips them).

    Args:
        path: the ``.jsonl`` file ``ngp predict --out`` wrote.

    Returns:
        ``{image name: row}``, the names relative to the folder ``ngp predict`` was given.

    Raises:
        InputError: a line that is not such a row.
    """
    rows = {}
    with Path(path).open(encoding="utf-8") as file:
        for number, line in enumerate(file, 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except ValueError:
                row = None
            if not isinstance(row, dict) or not isinstance(row.get("image"), str):
                raise InputError(f"{path}:{number}: not a row of ngp predict (a JSON object with an image name)")
            rows[row["image"]] = row
    return rows


def write_colmap_database(
    database: str | Path, calibrations: Mapping[str, Calibration | Mapping], model: str | None = None
) -> ColmapReport:
    """Write each photo's camera and gravity prior into a COLMAP database, new or existing (see the module's notes on
    what is touched: nothing the photos do not own).

    Args:
        database: the database file (made where missing; an existing one must be COLMAP's,
            :func:`ngp_kornia.preflight.check_database`).
        calibrations: by image name (the path relative to COLMAP's image folder, ``/`` between folders), an unbatched
            :class:`Calibration` or a row of ``ngp predict`` (:func:`read_predictions`).
        model: the COLMAP camera model, as for :meth:`Calibration.to_colmap`; None: ``SIMPLE_PINHOLE`` (``RADIAL``
            with a lens distortion).

    Returns:
        a :class:`ColmapReport`.

    Raises:
        InputError: a name that is not relative, or something else than a calibration or a row.
        OutputError: ``database`` is not a COLMAP database (nothing is written).
        ValueError: an unknown model, or a pinhole model for a calibration with a lens distortion.

    Example:
        >>> import pycolmap
        >>> from ngp_kornia.training.synth.render import render_scene
        >>> from ngp_kornia import calibrate
        >>> path = getfixture("tmp_path") / "db.db"
        >>> write_colmap_database(path, {"street.png": calibrate(render_scene(2).image)}).added
        ['street.png']
        >>> with pycolmap.Database.open(path) as db:
        ...     db.read_all_cameras()[0].has_prior_focal_length, db.read_all_pose_priors()[0].has_gravity()
        (True, True)
    """
    rows = {name: _row(name, calibrations[name]) for name in sorted(calibrations)}
    report, photos = ColmapReport(), {}
    for name, row in rows.items():
        photo = _photo(name, row, model)
        if isinstance(photo, str):
            report.skipped[name] = photo
        else:
            photos[name] = photo
    path = check_database(database)
    path.parent.mkdir(parents=True, exist_ok=True)
    with pycolmap.Database.open(path) as db, pycolmap.DatabaseTransaction(db):
        _write(db, photos, report)
    return report


def _write(db, photos: dict[str, _Photo], report: ColmapReport) -> None:
    images = {image.name: image for image in db.read_all_images()}
    cameras = {camera.camera_id: camera for camera in db.read_all_cameras()}
    users: dict[int, list[str]] = {}
    for image in images.values():
        users.setdefault(image.camera_id, []).append(image.name)
    priors = {(p.corr_data_id.sensor_id.id, p.corr_data_id.id): p for p in db.read_all_pose_priors()
              if p.corr_data_id.sensor_id.type == pycolmap.SensorType.CAMERA}
    for name, photo in photos.items():
        image = images.get(name)
        if image is None:
            _add(db, photo)
            report.added.append(name)
            continue
        camera = cameras[image.camera_id]
        if (camera.width, camera.height) != (photo.camera.width, photo.camera.height):
            report.skipped[name] = (f"COLMAP has it as {camera.width}x{camera.height} pixels, the calibration is of a "
                                    f"{photo.camera.width}x{photo.camera.height} file (another or a resized one?)")
            continue
        reason = _why_camera_is_kept(users[image.camera_id], photos)
        if reason is None:
            _update_camera(db, camera, photo.camera)
        else:
            report.camera_kept[name] = reason
        _write_gravity(db, priors.get((image.camera_id, image.image_id)), image, photo.gravity)
        report.updated.append(name)


def _why_camera_is_kept(users: list[str], photos: dict[str, _Photo]) -> str | None:
    """Why a camera of the database may not be changed (None: it may): it is shared with images not written, or
    the photos sharing it give it different parameters."""
    others = [name for name in users if name not in photos]
    if others:
        return f"its camera is shared with {len(others)} other images (e.g. {others[0]}); left as it is"
    first = photos[users[0]].camera
    for name in users[1:]:
        camera = photos[name].camera
        same = camera.model == first.model and np.allclose(camera.params, first.params, rtol=SAME_CAMERA_RTOL)
        if not same:
            return (f"its camera is shared with {name}, whose calibration differs (ngp predict --same-camera gives "
                    "them one); left as it is")
    return None


def _update_camera(db, camera, ours) -> None:
    """The database's camera takes our model and parameters, keeping its id."""
    camera.model, camera.params = ours.model, ours.params
    camera.width, camera.height = ours.width, ours.height
    camera.has_prior_focal_length = True
    db.update_camera(camera)


def _add(db, photo: _Photo) -> None:
    """A new image with its own camera, rig and frame (as COLMAP's image reader adds one), and its gravity."""
    camera = photo.camera
    camera.camera_id = db.write_camera(camera)
    rig = pycolmap.Rig()
    rig.add_ref_sensor(camera.sensor_id)
    rig.rig_id = db.write_rig(rig)
    image = pycolmap.Image(name=photo.name, camera_id=camera.camera_id)
    image.image_id = db.write_image(image)
    frame = pycolmap.Frame()
    frame.rig_id = rig.rig_id
    frame.add_data_id(image.data_id)
    db.write_frame(frame)
    _write_gravity(db, None, image, photo.gravity)


def _write_gravity(db, prior, image, gravity: np.ndarray) -> None:
    """Set the gravity of the image's pose prior (made where it has none; the rest of one it has is kept)."""
    if prior is None:
        prior = pycolmap.PosePrior()
        prior.corr_data_id = image.data_id
        prior.gravity = gravity
        db.write_pose_prior(prior)
        return
    prior.gravity = gravity
    db.update_pose_prior(prior)

