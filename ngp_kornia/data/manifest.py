r"""Images with ground-truth calibration listed in a CSV file.

Format: a UTF-8 CSV file whose first line names the columns (case-insensitive, in any order). Only ``image`` is
required; every other column may be absent or left empty on any row::

    image,focal_px,fov_deg,pitch_deg,roll_deg,horizon_x0,horizon_y0,horizon_x1,horizon_y1,zenith_x,zenith_y,zenith_w
    street/0001.jpg,512.0,,4.5,-1.2,,,,,,,
    street/0002.jpg,,62.0,,,-0.5,250.3,639.5,241.8,,,
    indoor/0003.png,,,,,,,,,30.1,-2400.0,1.0

* ``image``: the image file, relative to the CSV file's folder (or to ``root`` when given); absolute paths work.
* ``focal_px``: focal length in pixels (square pixels, principal point at the image centre).
* ``fov_deg``: **vertical** field of view in degrees; with ``focal_px`` on the same row they must agree within 1 %.
* ``pitch_deg``, ``roll_deg``: degrees; pitch > 0 looks up, roll > 0 when the scene's up leans right in the image.
* ``horizon_x0, horizon_y0, horizon_x1, horizon_y1``: two distinct points on the horizon line, in pixels.
* ``zenith_x, zenith_y, zenith_w``: the zenith (vertical) vanishing point in homogeneous pixels, at
  ``(zenith_x / zenith_w, zenith_y / zenith_w)``; ``zenith_w = 0`` puts it at infinity.
* Any other column is kept as text in :attr:`ManifestSample.extra`.

Pixels are x right, y down, with the origin at the centre of the top-left pixel, and angles follow
:mod:`ngp_kornia.geometry.camera`. A group (horizon, zenith) is given with all its columns or none. Empty cells and
``nan`` mean "unknown" and come back as ``None``.

Each sample holds what its row gives plus whatever follows from it, using the image size (read from the file's
header on first access): the focal length from the field of view and back; with a focal length, the up vector,
pitch, roll, horizon and zenith from any one of pitch + roll, the horizon or the zenith; the roll alone from a
horizon or zenith without a focal length. When a row gives the same quantity twice (focal and field of view, or
two of pitch / roll, horizon and zenith) the values must agree, within 1 % for the focal length and 1 degree for
the up direction, or reading that row raises an error naming the line.

The CSV and the image files are checked when the manifest is built (header, numbers, ranges, incomplete groups,
missing files); the checks that need the image size run when a sample is read. :meth:`CSVManifest.validate` reads
every sample at once.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import torch
from torch import Tensor

from ngp_kornia.errors import ManifestError
from ngp_kornia.geometry.camera import (
    focal_from_fov,
    fov_from_focal,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    pitch_roll_from_up,
    rotation_from_angles,
    up_from_rotation,
    up_from_zenith,
    zenith_from_horizon,
    zenith_from_up,
)
from ngp_kornia.io import ImageError, exif_orientation, header_size, read_image_file

__all__ = ["COLUMNS", "CSVManifest", "ManifestError", "ManifestSample", "read_image_size"]

HORIZON_COLUMNS = ("horizon_x0", "horizon_y0", "horizon_x1", "horizon_y1")
ZENITH_COLUMNS = ("zenith_x", "zenith_y", "zenith_w")
NUMBER_COLUMNS = ("focal_px", "fov_deg", "pitch_deg", "roll_deg", *HORIZON_COLUMNS, *ZENITH_COLUMNS)
COLUMNS = ("image", *NUMBER_COLUMNS)
MISSING = frozenset({"", "nan", "na", "n/a", "none", "null"})
MAX_LISTED = 5  # missing files named in the error message

_RANGES = {  # column: (low, high, inclusive, what the value means)
    "focal_px": (0.0, math.inf, False, "a focal length in pixels must be positive"),
    "fov_deg": (0.0, 180.0, False, "a vertical field of view must lie in (0, 180) degrees"),
    "pitch_deg": (-90.0, 90.0, True, "pitch must lie in [-90, 90] degrees"),
    "roll_deg": (-180.0, 180.0, True, "roll must lie in [-180, 180] degrees"),
}
_F64 = torch.float64


@dataclass(frozen=True)
class ManifestSample:
    """One row of a :class:`CSVManifest` with its ground truth (float64 tensors, degrees, pixels).

    Every geometric field is ``None`` when the row neither gives it nor lets it be derived.

    Attributes:
        image_path: the image file.
        line: the row's line number in the CSV file (the header is line 1).
        height: image height in pixels.
        width: image width in pixels.
        focal: focal length in pixels.
        fov_v: vertical field of view, degrees.
        fov_h: horizontal field of view, degrees.
        pitch: degrees, > 0 looking up.
        roll: degrees.
        K: (3, 3) intrinsics, principal point at the image centre.
        up: (3,) unit up vector in camera coordinates.
        zenith: (3,) homogeneous zenith VP in pixels, unit norm.
        horizon: (3,) horizon line ``(a, b, c)`` in pixels, ``a^2 + b^2 = 1``, ``b >= 0``.
        extra: the row's other columns, as text.
    """

    image_path: Path
    line: int
    height: int
    width: int
    focal: float | None = None
    fov_v: float | None = None
    fov_h: float | None = None
    pitch: float | None = None
    roll: float | None = None
    K: Tensor | None = None
    up: Tensor | None = None
    zenith: Tensor | None = None
    horizon: Tensor | None = None
    extra: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class _Row:
    line: int
    image_path: Path
    values: dict[str, float | None]
    extra: dict[str, str]

    def has(self, *names: str) -> bool:
        return all(self.values[n] is not None for n in names)


def read_image_size(path: str | Path) -> tuple[int, int]:
    """``(height, width)`` of an image file: from its header (:func:`ngp_kornia.io.header_size`), else by decoding it.

    The size is the one :func:`ngp_kornia.io.read_image_file` decodes: as displayed, after the EXIF orientation.

    Raises:
        ImageError: missing or unreadable files.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
            size = header_size(head)
            if size is None and head[:2] == b"\xff\xd8":  # large metadata blocks before the frame header
                size = header_size(head + f.read())
            if size is not None and exif_orientation(head) >= 5:  # stored turned by 90 degrees
                size = size[::-1]
    except OSError:
        size = None
    if size is not None:
        return size
    rgb = read_image_file(path)
    return int(rgb.shape[0]), int(rgb.shape[1])


def _parse_number(text: str | None, column: str, where: str) -> float | None:
    if text is None or text.strip().lower() in MISSING:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ManifestError(f"{where}: column {column!r}: {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise ManifestError(f"{where}: column {column!r}: {text.strip()!r} is not a finite number")
    low, high, inclusive, meaning = _RANGES.get(column, (-math.inf, math.inf, True, ""))
    inside = low <= value <= high if inclusive else low < value < high
    if not inside:
        raise ManifestError(f"{where}: column {column!r}: {value:g} is out of range; {meaning}")
    return value


def _check_group(values: dict[str, float | None], columns: tuple[str, ...], where: str) -> None:
    given = [c for c in columns if values[c] is not None]
    if given and len(given) != len(columns):
        missing = [c for c in columns if values[c] is None]
        raise ManifestError(f"{where}: {', '.join(given)} given without {', '.join(missing)}; give all or none")


def _check_geometry(values: dict[str, float | None], where: str) -> None:
    _check_group(values, HORIZON_COLUMNS, where)
    _check_group(values, ZENITH_COLUMNS, where)
    if values["horizon_x0"] is not None:
        x0, y0, x1, y1 = (values[c] for c in HORIZON_COLUMNS)
        if math.hypot(x1 - x0, y1 - y0) < 1e-6:
            raise ManifestError(f"{where}: the two horizon points coincide; give two distinct points on the line")
    if values["zenith_x"] is not None and all(values[c] == 0 for c in ZENITH_COLUMNS):
        raise ManifestError(f"{where}: the zenith (0, 0, 0) is not a point; zenith_w = 0 needs a direction x, y")


def _read_csv(path: Path) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """The normalised header and the non-blank rows with their line numbers."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            rows = [(reader.line_num, r) for r in reader if any(v.strip() for v in r)]
    except UnicodeDecodeError as e:
        raise ManifestError(f"{path}: not a UTF-8 text file ({e}); save the manifest as UTF-8 CSV") from None
    except csv.Error as e:
        raise ManifestError(f"{path}: malformed CSV: {e}") from None
    if header is None:
        raise ManifestError(f"{path}: file is empty; the first line must name the columns, e.g. image,focal_px")
    names = [h.strip().lower() for h in header]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ManifestError(f"{path}, line 1: duplicate column(s) {duplicates}; name every column once")
    if "image" not in names:
        raise ManifestError(
            f"{path}, line 1: no 'image' column (header: {names}); the first line must name the columns, "
            f"e.g. image,focal_px,pitch_deg,roll_deg"
        )
    out = []
    for line, r in rows:
        if len(r) > len(names):
            raise ManifestError(f"{path}, line {line}: {len(r)} fields but the header names {len(names)} columns")
        out.append((line, dict(zip(names, r, strict=False))))
    return names, out


class CSVManifest(Sequence[ManifestSample]):
    """Images and their ground-truth calibration from a CSV manifest (format: see the module docstring).

    Args:
        path: the CSV file.
        root: folder the image paths are relative to; the CSV file's folder when omitted.
        focal_tolerance: largest relative difference allowed between ``focal_px`` and ``fov_deg``.
        angle_tolerance: largest angle in degrees allowed between up directions given twice on a row.

    Raises:
        FileNotFoundError: the CSV file, ``root`` or listed image files are missing (the first few are named).
        ManifestError: a malformed CSV (no ``image`` column, unparsable or out-of-range numbers, incomplete
            horizon or zenith), naming the line. Contradictions are reported when the sample is read.

    Usage::

        data = CSVManifest("labels.csv")
        for s in data:
            s.image_path, s.focal, s.pitch, s.roll, s.horizon  # None where unknown

    Example:
        >>> CSVManifest("/no/such/labels.csv")
        Traceback (most recent call last):
        ...
        FileNotFoundError: manifest not found: /no/such/labels.csv
    """

    def __init__(
        self,
        path: str | Path,
        root: str | Path | None = None,
        focal_tolerance: float = 0.01,
        angle_tolerance: float = 1.0,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"manifest not found: {self.path}")
        self.root = self.path.parent if root is None else Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"image root not found (or not a folder): {self.root}")
        if not (focal_tolerance >= 0 and angle_tolerance >= 0):
            raise ValueError(f"tolerances must be >= 0, got {focal_tolerance} and {angle_tolerance}")
        self.focal_tolerance = float(focal_tolerance)
        self.angle_tolerance = float(angle_tolerance)
        _, records = _read_csv(self.path)
        self._rows = [self._parse(line, record) for line, record in records]
        self._check_files()
        self._sizes: dict[int, tuple[int, int]] = {}

    def _where(self, line: int) -> str:
        return f"{self.path}, line {line}"

    def _parse(self, line: int, record: dict[str, str]) -> _Row:
        where = self._where(line)
        image = (record.get("image") or "").strip()
        if not image:
            raise ManifestError(f"{where}: the 'image' cell is empty; give the image file's path")
        values = {c: _parse_number(record.get(c), c, where) for c in NUMBER_COLUMNS}
        _check_geometry(values, where)
        extra = {k: v for k, v in record.items() if k not in COLUMNS}
        return _Row(line, self.root / Path(image).expanduser(), values, extra)

    def _check_files(self) -> None:
        missing = [r for r in self._rows if not r.image_path.is_file()]
        if not missing:
            return
        listed = "; ".join(f"line {r.line}: {r.image_path}" for r in missing[:MAX_LISTED])
        more = f" and {len(missing) - MAX_LISTED} more" if len(missing) > MAX_LISTED else ""
        raise FileNotFoundError(
            f"{self.path}: {len(missing)} listed image file(s) not found (paths are relative to {self.root}): "
            f"{listed}{more}"
        )

    @property
    def image_paths(self) -> list[Path]:
        """The image files in CSV order (reads no image)."""
        return [r.image_path for r in self._rows]

    def image_size(self, index: int) -> tuple[int, int]:
        """``(height, width)`` of image ``index``, read from the file header once and cached."""
        row = self._rows[index]
        if row.line not in self._sizes:
            try:
                self._sizes[row.line] = read_image_size(row.image_path)
            except ImageError as e:
                raise ImageError(f"{self._where(row.line)}: {e}") from None
        return self._sizes[row.line]

    def _sample(self, index: int) -> ManifestSample:
        row = self._rows[index]
        height, width = self.image_size(index)
        return _derive(row, height, width, self._where(row.line), self.focal_tolerance, self.angle_tolerance)

    def validate(self) -> list[ManifestSample]:
        """Read every sample (every image header), raising the first error; returns the samples."""
        return [self._sample(i) for i in range(len(self))]

    def __len__(self) -> int:
        return len(self._rows)

    @overload
    def __getitem__(self, index: int) -> ManifestSample: ...

    @overload
    def __getitem__(self, index: slice) -> list[ManifestSample]: ...

    def __getitem__(self, index: int | slice) -> ManifestSample | list[ManifestSample]:
        if isinstance(index, slice):
            return [self._sample(i) for i in range(len(self))[index]]
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for a manifest of {len(self)} images")
        return self._sample(index % len(self))

    def __iter__(self) -> Iterator[ManifestSample]:
        return (self._sample(i) for i in range(len(self)))

    def __repr__(self) -> str:
        return f"CSVManifest(path={str(self.path)!r}, root={str(self.root)!r}, images={len(self)})"


def _t(*values: float) -> Tensor:
    return torch.tensor([values], dtype=_F64)


def _focal(row: _Row, height: int, where: str, tolerance: float) -> float | None:
    focal, fov = row.values["focal_px"], row.values["fov_deg"]
    if fov is None:
        return focal
    from_fov = float(focal_from_fov(_t(fov)[0], height)[0])
    if focal is not None and abs(focal - from_fov) > tolerance * from_fov:
        raise ManifestError(
            f"{where}: focal_px {focal:g} and fov_deg {fov:g} disagree: a {fov:g} degree vertical field of view "
            f"over {height} rows is a focal length of {from_fov:.1f} px ({abs(focal / from_fov - 1):.1%} apart); "
            f"correct or drop one of them"
        )
    return from_fov if focal is None else focal


def _up_sources(row: _Row, K: Tensor) -> dict[str, Tensor]:
    """Up vectors (1, 3) from the horizon and the zenith of a row, with intrinsics ``K`` (1, 3, 3)."""
    ups = {}
    if row.has(*HORIZON_COLUMNS):
        x0, y0, x1, y1 = (row.values[c] for c in HORIZON_COLUMNS)
        line = torch.linalg.cross(_t(x0, y0, 1.0), _t(x1, y1, 1.0))
        ups["horizon"] = up_from_zenith(K, zenith_from_horizon(K, line))
    if row.has(*ZENITH_COLUMNS):
        ups["zenith"] = up_from_zenith(K, _t(*(row.values[c] for c in ZENITH_COLUMNS)))
    return ups


def _angle_deg(a: Tensor, b: Tensor) -> float:
    """Angle between two up directions; up to sign, as a horizon or zenith does not tell up from down."""
    return math.degrees(math.acos(min(1.0, abs(float((normalize(a) * normalize(b)).sum())))))


def _roll_gap(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _check_agreement(diffs: dict[str, float], where: str, tolerance: float) -> None:
    for names, diff in diffs.items():
        if diff > tolerance:
            raise ManifestError(
                f"{where}: {names} disagree by {diff:.2f} degrees (tolerance {tolerance:g}); correct or drop one"
            )


def _angles_up(pitch: float, roll: float) -> Tensor:
    return up_from_rotation(rotation_from_angles(_t(pitch)[0], _t(roll)[0]))


def _up_and_angles(row: _Row, sources: dict[str, Tensor], known_focal: bool, where: str, tol: float):
    """The row's up vector (1, 3) or None, pitch and roll, after checking that the row's sources agree."""
    pitch, roll = row.values["pitch_deg"], row.values["roll_deg"]
    if known_focal:
        ups = dict(sources)
        if pitch is not None and roll is not None:
            ups = {"pitch_deg/roll_deg": _angles_up(pitch, roll), **ups}
        if not ups:
            return None, pitch, roll
        (first, up), *others = ups.items()
        _check_agreement({f"{first} and {n}": _angle_deg(up, u) for n, u in others}, where, tol)
        p, r = (float(v) for v in pitch_roll_from_up(up))
        if pitch is not None:
            _check_agreement({f"pitch_deg and {first}": abs(pitch - p)}, where, tol)
        if roll is not None:
            _check_agreement({f"roll_deg and {first}": _roll_gap(roll, r)}, where, tol)
        return up, p if pitch is None else pitch, r if roll is None else roll
    # without a focal length only the roll can be compared and derived
    rolls = {"roll_deg": roll} if roll is not None else {}
    rolls.update({n: float(pitch_roll_from_up(u)[1]) for n, u in sources.items()})
    if rolls:
        (first, roll), *others = rolls.items()
        _check_agreement({f"{first} and {n}": _roll_gap(roll, r) for n, r in others}, where, tol)
    up = None if pitch is None or roll is None else _angles_up(pitch, roll)
    return up, pitch, roll


def _derive(row: _Row, height: int, width: int, where: str, focal_tol: float, angle_tol: float) -> ManifestSample:
    focal = _focal(row, height, where, focal_tol)
    centre = image_center(height, width, like=torch.zeros((), dtype=_F64))
    # without a focal length any positive value gives the right roll, zenith sign and horizon direction
    K = intrinsics_matrix(_t(float(height) if focal is None else focal)[0], centre)
    sources = _up_sources(row, K)
    up, pitch, roll = _up_and_angles(row, sources, focal is not None, where, angle_tol)
    horizon = zenith = None
    if "zenith" in sources or (focal is not None and up is not None):
        zenith = normalize(zenith_from_up(K, sources.get("zenith", up)))[0]
    if "horizon" in sources or (focal is not None and up is not None):
        horizon = horizon_from_zenith(K, zenith_from_up(K, sources.get("horizon", up)))[0]
    f = None if focal is None else _t(focal)[0]
    return ManifestSample(
        image_path=row.image_path,
        line=row.line,
        height=height,
        width=width,
        focal=focal,
        fov_v=None if f is None else float(fov_from_focal(f, height)[0]),
        fov_h=None if f is None else float(fov_from_focal(f, width)[0]),
        pitch=pitch,
        roll=roll,
        K=None if f is None else K[0],
        up=None if up is None else up[0],
        zenith=zenith,
        horizon=horizon,
        extra=dict(row.extra),
    )
