"""Priors and trust on the command line, in ngp predict, in calibrate() for files and in the overlay."""

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from ngp_kornia import calibrate
from ngp_kornia.cli import main
from ngp_kornia.io import FILM_DIAGONAL_MM
from ngp_kornia.pipeline import ParserConfig
from ngp_kornia.predict import predict_folder
from ngp_kornia.rows import result_row
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.viz import draw_calibration
from tests.image_files import SHORT, tiff_block

TRUST = ("confidence", "pitch_std", "roll_std", "fov_v_std")


def _scene_jpeg(path, exif_35mm: int | None) -> np.ndarray:
    rgb = render_scene(2, size=(160, 120)).image
    data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    if exif_35mm is not None:
        segment = b"Exif\x00\x00" + tiff_block("II", [(0xA405, SHORT, exif_35mm)])
        data = data[:2] + b"\xff\xe1" + (len(segment) + 2).to_bytes(2, "big") + segment + data[2:]
    path.write_bytes(data)
    return rgb


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    root = tmp_path_factory.mktemp("priors")
    _scene_jpeg(root / "with_exif.jpg", 30)
    _scene_jpeg(root / "plain.jpg", None)
    return root


EXIF_FOCAL = 30 * math.hypot(160, 120) / FILM_DIAGONAL_MM


def _rows(capsys):
    return [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]


def test_cli_focal_and_fov_priors_and_trust_fields(photos, capsys):
    image = str(photos / "plain.jpg")
    assert main(["calibrate", image, "--focal", "150"]) == 0
    row = _rows(capsys)[0]
    assert row["focal"] == pytest.approx(150.0, rel=1e-5) and row["fov_v_std"] == 0.0
    assert all(0.0 <= row[k] for k in TRUST) and row["confidence"] <= 1.0
    assert main(["calibrate", image, "--fov", "50"]) == 0
    assert _rows(capsys)[0]["fov_v"] == pytest.approx(50.0, abs=1e-3)


def test_cli_exif_prior_and_silent_fall_back(photos, capsys):
    assert main(["calibrate", str(photos / "with_exif.jpg"), str(photos / "plain.jpg"), "--exif"]) == 0
    with_exif, plain = _rows(capsys)
    assert with_exif["focal"] == pytest.approx(EXIF_FOCAL, rel=1e-5)
    assert plain == json.loads(json.dumps(result_row(plain["image"], calibrate(str(photos / "plain.jpg")))))


def test_calibrate_reads_exif_only_when_asked(photos):
    path = str(photos / "with_exif.jpg")
    assert float(calibrate(path, priors={"exif": True}).focal) == pytest.approx(EXIF_FOCAL, rel=1e-5)
    assert float(calibrate(path).focal) != pytest.approx(EXIF_FOCAL, rel=1e-5)
    given_wins = calibrate(path, priors={"exif": True, "focal": 200.0})
    assert float(given_wins.focal) == pytest.approx(200.0, rel=1e-5)


def test_predict_uses_each_files_exif(photos, tmp_path):
    out = tmp_path / "rows.jsonl"

    predict_folder(photos, out, exif=True)
    rows = {r["image"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert rows["with_exif.jpg"]["focal"] == pytest.approx(EXIF_FOCAL, rel=1e-5)
    assert rows["plain.jpg"]["focal"] == pytest.approx(float(calibrate(str(photos / "plain.jpg")).focal), rel=1e-5)
    assert all(k in rows["plain.jpg"] for k in TRUST)


def test_overlay_writes_the_confidence_line():
    rgb = render_scene(2, size=(320, 240)).image
    cal = calibrate(rgb)
    with_trust = draw_calibration(rgb, cal)
    without = draw_calibration(rgb, replace(cal, confidence=None))
    assert (with_trust[240:40 + 240] != without[240:40 + 240]).any()  # the strip's first rows: the numbers
    assert (with_trust[:240] == without[:240]).all()  # the photo's part is the same


def test_cli_centre_std_widens_only_the_stds(photos, capsys, tmp_path):
    image = str(photos / "plain.jpg")
    rows = []
    for value in ("0", "0.025", "0.05"):
        assert main(["calibrate", image, "--trust.centre_std", value]) == 0
        rows.append(_rows(capsys)[0])
    assert rows[0]["pitch_std"] < rows[1]["pitch_std"] < rows[2]["pitch_std"]
    assert all(r["pitch"] == rows[0]["pitch"] and r["confidence"] == rows[0]["confidence"] for r in rows)
    assert main(["calibrate", image]) == 0 and _rows(capsys)[0]["pitch_std"] == rows[1]["pitch_std"]  # the default
    out = tmp_path / "rows.jsonl"
    assert main(["predict", str(photos), "--out", str(out), "--trust.centre_std", "0"]) == 0
    plain = [json.loads(line) for line in out.read_text().splitlines() if "plain.jpg" in line][0]
    assert plain["pitch_std"] == pytest.approx(rows[0]["pitch_std"], rel=1e-5)
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", image, "--trust.centre_std", "-1"])
    assert exit_info.value.code == 2 and "centre_std" in capsys.readouterr().err


def test_cli_working_size_reaches_the_line_detector(capsys, tmp_path):
    rgb = render_scene(4, size=(800, 600)).image  # larger than 640: the working size decides the detection
    image = tmp_path / "large.png"
    cv2.imwrite(str(image), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert main(["calibrate", str(image), "--segments.working_size", "640"]) == 0
    small = _rows(capsys)[0]
    assert main(["calibrate", str(image)]) == 0
    full = _rows(capsys)[0]
    expected = calibrate(str(image), config=ParserConfig().replace(working_size=640))
    assert small["focal"] == pytest.approx(float(expected.focal), rel=1e-6) and small["focal"] != full["focal"]
    out = tmp_path / "rows.jsonl"
    assert main(["predict", str(tmp_path), "--out", str(out), "--segments.working_size", "640"]) == 0
    assert json.loads(out.read_text().splitlines()[0])["focal"] == pytest.approx(small["focal"], rel=1e-5)
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", str(image), "--segments.working_size", "0"])
    assert exit_info.value.code == 2 and "SegmentSettings.working_size" in capsys.readouterr().err


def test_cli_polish_frame_gives_the_polished_answer(capsys, tmp_path):
    rgb = render_scene(3, size=(640, 480)).image  # a scene where the polish moves the frame
    image = tmp_path / "scene.png"
    cv2.imwrite(str(image), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert main(["calibrate", str(image), "--polish.enabled", "true"]) == 0
    polished = _rows(capsys)[0]
    assert main(["calibrate", str(image)]) == 0
    plain = _rows(capsys)[0]
    expected = calibrate(str(image), config=ParserConfig().replace(**{"polish.enabled": True}))
    assert polished["pitch"] == pytest.approx(float(expected.pitch), rel=1e-5) and polished["pitch"] != plain["pitch"]
    out = tmp_path / "rows.jsonl"
    assert main(["predict", str(tmp_path), "--out", str(out), "--polish.enabled", "true"]) == 0
    assert json.loads(out.read_text().splitlines()[0])["pitch"] == pytest.approx(polished["pitch"], abs=1e-5)


def test_cli_focal_priors_in_three_units_one_at_a_time(photos, capsys):
    image = str(photos / "plain.jpg")
    assert main(["calibrate", image, "--focal-35mm", "30"]) == 0
    assert _rows(capsys)[0]["focal"] == pytest.approx(EXIF_FOCAL, rel=1e-5)
    with pytest.raises(SystemExit) as stop:  # --fov was once dropped without a word
        main(["calibrate", image, "--focal", "500", "--fov", "90"])
    assert stop.value.code == 2 and "argument --fov: not allowed with argument --focal" in capsys.readouterr().err
    assert main(["calibrate", image, "--focal", "5"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "millimetres? give it as focal_35mm= (--focal-35mm)" in err


def test_an_exif_focal_length_no_camera_has_is_no_prior(tmp_path):
    path = tmp_path / "odd.jpg"
    _scene_jpeg(path, 1)  # a 1 mm equivalent: a damaged tag, not a lens
    assert float(calibrate(str(path), priors={"exif": True}).focal) == pytest.approx(float(calibrate(str(path)).focal))
