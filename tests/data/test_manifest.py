import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ngp_kornia.data.manifest import CSVManifest, ManifestError, ManifestSample, read_image_size
from ngp_kornia.geometry.camera import (
    focal_from_fov,
    horizon_border_points,
    horizon_from_zenith,
    image_center,
    intrinsics_matrix,
    normalize,
    rotation_from_angles,
    up_from_rotation,
    zenith_from_up,
)
from ngp_kornia.io import ImageError

HORIZON = ["horizon_x0", "horizon_y0", "horizon_x1", "horizon_y1"]
ZENITH = ["zenith_x", "zenith_y", "zenith_w"]
# name: (width, height, fov_v, pitch, roll, yaw)
CAMERAS = {
    "a.jpg": (160, 120, 60.0, 10.0, -5.0, 20.0),
    "b.png": (96, 128, 45.0, -20.0, 12.0, -70.0),
    "sub/c.png": (120, 90, 75.0, 3.0, 0.0, 0.0),
    "d.jpg": (100, 100, 50.0, 0.0, 7.0, 0.0),  # zenith at infinity
}


def _image(path: Path, width: int, height: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    image = np.random.default_rng(0).integers(0, 255, (height, width, 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), image)
    return path


def _csv(path: Path, header: list[str], rows: list[list]) -> Path:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def _truth(width, height, fov, pitch, roll, yaw) -> dict:
    """Ground truth of a camera from the camera module alone."""
    t = [torch.tensor([v], dtype=torch.float64) for v in (fov, pitch, roll, yaw)]
    focal = focal_from_fov(t[0], height)
    K = intrinsics_matrix(focal, image_center(height, width, like=focal))
    up = up_from_rotation(rotation_from_angles(t[1], t[2], t[3]))
    zenith = zenith_from_up(K, up)
    horizon = horizon_from_zenith(K, zenith)
    ends = horizon_border_points(horizon, width)[0]
    return {
        "K": K[0],
        "up": up[0],
        "focal": float(focal[0]),
        "zenith": normalize(zenith)[0],
        "horizon": horizon[0],
        "ends": ends.flatten().tolist(),
        "zenith_raw": (zenith[0] * 7.0).tolist(),
    }


def _row(name: str, columns: list[str]) -> list:
    width, height, fov, pitch, roll, yaw = CAMERAS[name]
    gt = _truth(*CAMERAS[name])
    values = {"image": name, "focal_px": gt["focal"], "fov_deg": fov, "pitch_deg": pitch, "roll_deg": roll}
    values.update(zip(HORIZON, gt["ends"], strict=True))
    values.update(zip(ZENITH, gt["zenith_raw"], strict=True))
    return [f"{values[c]:.10g}" if isinstance(values[c], float) else values[c] for c in columns]


@pytest.fixture()
def folder(tmp_path: Path) -> Path:
    for name, (width, height, *_) in CAMERAS.items():
        _image(tmp_path / name, width, height)
    return tmp_path


def _check_truth(sample: ManifestSample, name: str, with_focal: bool = True) -> None:
    width, height, fov, pitch, roll, _ = CAMERAS[name]
    gt = _truth(*CAMERAS[name])
    assert (sample.height, sample.width) == (height, width)
    assert sample.pitch == pytest.approx(pitch, abs=1e-6) and sample.roll == pytest.approx(roll, abs=1e-6)
    assert torch.allclose(sample.horizon, gt["horizon"], atol=1e-6)
    if with_focal:
        assert sample.focal == pytest.approx(gt["focal"]) and sample.fov_v == pytest.approx(fov)
        h_fov = 2 * np.degrees(np.arctan(width / 2 / gt["focal"]))
        assert sample.fov_h == pytest.approx(h_fov)
        assert torch.allclose(sample.K, gt["K"]) and torch.allclose(sample.up, gt["up"], atol=1e-8)
        assert torch.allclose(sample.zenith, gt["zenith"], atol=1e-8)


@pytest.mark.parametrize(
    "columns",
    [
        ["focal_px", "pitch_deg", "roll_deg"],
        ["fov_deg", *HORIZON],
        ["focal_px", *ZENITH],
        ["focal_px", "fov_deg", "pitch_deg", "roll_deg", *HORIZON, *ZENITH],
    ],
    ids=["angles", "horizon", "zenith", "all"],
)
def test_round_trip_from_known_cameras(folder, columns):
    header = ["image", *columns]
    path = _csv(folder / "labels.csv", header, [_row(name, header) for name in CAMERAS])
    data = CSVManifest(path)
    assert len(data) == 4 and data.image_paths == [folder / n for n in CAMERAS]
    for sample, name in zip(data, CAMERAS, strict=True):
        assert sample.image_path == folder / name
        _check_truth(sample, name)
    assert [s.line for s in data] == [2, 3, 4, 5]


def test_rows_without_focal(folder):
    header = ["image", "pitch_deg", "roll_deg", *HORIZON, *ZENITH]
    name = "a.jpg"
    gt = _truth(*CAMERAS[name])
    rows = [
        [name, "", "", *_row(name, ["image", *HORIZON])[1:], "", "", ""],  # horizon only: roll, no pitch
        [name, "", "", "", "", "", "", *_row(name, ["image", *ZENITH])[1:]],  # zenith only
        [name, "10", "-5"],  # angles only (a short row): up but no horizon
        [name, "nan", "NaN", "", "", "", ""],  # nothing
    ]
    data = CSVManifest(_csv(folder / "m.csv", header, rows))
    horizon_only, zenith_only, angles_only, nothing = data
    assert horizon_only.pitch is None and horizon_only.roll == pytest.approx(-5.0)
    assert torch.allclose(horizon_only.horizon, gt["horizon"]) and horizon_only.zenith is None
    assert horizon_only.focal is None and horizon_only.K is None and horizon_only.up is None
    assert zenith_only.roll == pytest.approx(-5.0) and torch.allclose(zenith_only.zenith, gt["zenith"])
    assert zenith_only.horizon is None and zenith_only.fov_v is None
    assert angles_only.pitch == 10.0 and torch.allclose(angles_only.up, gt["up"]) and angles_only.horizon is None
    for field in ("focal", "fov_v", "fov_h", "pitch", "roll", "K", "up", "zenith", "horizon"):
        assert getattr(nothing, field) is None, field


def test_root_paths_header_and_extra_columns(folder, tmp_path):
    elsewhere = tmp_path / "csvs"
    elsewhere.mkdir()
    path = elsewhere / "m.csv"
    path.write_text(
        f"\ufeff Image , Focal_PX ,split\na.jpg,300,train\n\n{folder / 'b.png'},400,test\n",
        encoding="utf-8",
    )
    data = CSVManifest(path, root=folder)
    assert data.image_paths == [folder / "a.jpg", folder / "b.png"]
    assert data[0].extra == {"split": "train"} and data[1].extra == {"split": "test"}
    assert data[-1].line == 4 and data[1].focal == 400.0
    assert [s.line for s in data[0:2]] == [2, 4]
    assert "images=2" in repr(data)
    with pytest.raises(IndexError):
        data[2]


def test_image_size_from_headers(tmp_path):
    gray = np.zeros((33, 47), np.uint8)
    cases = {
        "x.png": (np.zeros((21, 34, 3), np.uint8), []),
        "x.jpg": (np.zeros((50, 31, 3), np.uint8), []),
        "p.jpg": (np.zeros((40, 64, 3), np.uint8), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
        "g.jpg": (gray, []),
        "x.bmp": (np.zeros((17, 19, 3), np.uint8), []),  # decoded
    }
    for name, (image, params) in cases.items():
        assert cv2.imwrite(str(tmp_path / name), image, params)
        assert read_image_size(tmp_path / name) == image.shape[:2], name
    with pytest.raises(ImageError, match="not found"):
        read_image_size(tmp_path / "none.png")
    (tmp_path / "bad.png").write_bytes(b"not an image at all")
    with pytest.raises(ImageError, match="not a readable image"):
        read_image_size(tmp_path / "bad.png")


@pytest.mark.parametrize(
    "text,match",
    [
        ("", "file is empty"),
        ("path,focal_px\na.jpg,500\n", "line 1: no 'image' column"),
        ("image,focal_px,FOCAL_PX\na.jpg,1,1\n", "line 1: duplicate column"),
        ("image,focal_px\na.jpg,500\nb.png,5OO\n", "line 3: column 'focal_px': '5OO' is not a number"),
        ("image,pitch_deg\na.jpg,inf\n", "line 2: column 'pitch_deg': 'inf' is not a finite number"),
        ("image,fov_deg\na.jpg,200\n", "line 2: column 'fov_deg': 200 is out of range"),
        ("image,focal_px\na.jpg,-3\n", "line 2: column 'focal_px': -3 is out of range"),
        ("image,pitch_deg\na.jpg,95\n", "line 2: .*pitch must lie in"),
        ("image,horizon_x0,horizon_y0,horizon_x1\na.jpg,0,1,2\n", "line 2: horizon_x0, horizon_y0, horizon_x1 given"),
        ("image,horizon_x0,horizon_y0,horizon_x1,horizon_y1\na.jpg,1,2,1,2\n", "line 2: the two horizon points"),
        ("image,zenith_x,zenith_y,zenith_w\na.jpg,0,0,0\n", "line 2: the zenith"),
        ("image,zenith_x,zenith_y\na.jpg,0,1\n", "without zenith_w"),
        ("image,focal_px\na.jpg,500,extra\n", "line 2: 3 fields but the header names 2"),
        ("image,focal_px\n ,500\n", "line 2: the 'image' cell is empty"),
    ],
)
def test_malformed_csv(folder, text, match):
    (folder / "m.csv").write_text(text)
    with pytest.raises(ManifestError, match=match):
        CSVManifest(folder / "m.csv")


def test_missing_files(folder, tmp_path):
    with pytest.raises(FileNotFoundError, match="manifest not found"):
        CSVManifest(folder / "none.csv")
    path = _csv(folder / "m.csv", ["image"], [["a.jpg"]] + [[f"gone{i}.jpg"] for i in range(7)] + [["sub"]])
    with pytest.raises(FileNotFoundError) as err:
        CSVManifest(path)
    message = str(err.value)
    assert "8 listed image file(s) not found" in message and "line 3:" in message and "gone4.jpg" in message
    assert "gone5.jpg" not in message and "and 3 more" in message
    with pytest.raises(FileNotFoundError, match="image root not found"):
        CSVManifest(path, root=tmp_path / "nowhere")
    with pytest.raises(ValueError, match="tolerances"):
        CSVManifest(_csv(folder / "ok.csv", ["image"], [["a.jpg"]]), focal_tolerance=-1)


def test_contradictions_name_the_line(folder):
    name = "a.jpg"
    gt = _truth(*CAMERAS[name])
    fov = CAMERAS[name][2]
    header = ["image", "focal_px", "fov_deg"]
    rows = [[name, gt["focal"] * 1.005, fov], [name, gt["focal"] * 1.02, fov]]
    data = CSVManifest(_csv(folder / "f.csv", header, rows))
    assert data[0].focal == pytest.approx(gt["focal"] * 1.005)  # within 1 %: the given focal is kept
    with pytest.raises(ManifestError, match=r"line 3: focal_px .* and fov_deg 60 disagree.*2\.0% apart"):
        data[1]
    with pytest.raises(ManifestError, match="line 3"):
        data.validate()
    assert len(CSVManifest(folder / "f.csv", focal_tolerance=0.05).validate()) == 2

    header = ["image", "focal_px", "pitch_deg", "roll_deg", *HORIZON, *ZENITH]
    good = _row(name, header)
    pitch_off = [*good[:2], "13", *good[3:]]
    zenith_off = good[:-3] + _row("b.png", ZENITH)
    roll_only = [*good[:2], "", "1", *good[4:]]
    data = CSVManifest(_csv(folder / "a.csv", header, [good, pitch_off, zenith_off, roll_only]))
    assert data[0].pitch == pytest.approx(10.0)
    with pytest.raises(ManifestError, match=r"line 3: pitch_deg/roll_deg and horizon disagree by 3\.\d+ degrees"):
        data[1]
    with pytest.raises(ManifestError, match="line 4: pitch_deg/roll_deg and zenith disagree"):
        data[2]
    with pytest.raises(ManifestError, match="line 5: roll_deg and horizon disagree by 6"):
        data[3]

    header = ["image", "roll_deg", *HORIZON, *ZENITH]  # no focal: only the roll is compared
    rows = [[name, "-5", *good[4:]], [name, "-5", *good[4:8], *_row("b.png", ZENITH)]]
    data = CSVManifest(_csv(folder / "r.csv", header, rows))
    assert data[0].roll == -5.0 and data[0].pitch is None
    with pytest.raises(ManifestError, match="line 3: roll_deg and zenith disagree"):
        data[1]


def test_unreadable_image_names_the_line(folder):
    (folder / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    data = CSVManifest(_csv(folder / "m.csv", ["image", "focal_px"], [["a.jpg", 100], ["bad.png", 100]]))
    assert data[0].width == 160
    with pytest.raises(ImageError, match=r"m\.csv, line 3: .*bad\.png"):
        data[1]
