"""The ngp command: JSON per image, overlays, one-line errors that do not stop the other images."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from ngp_kornia.cli import main
from tests.image_files import jpeg_with_orientation


@pytest.fixture
def photo(tmp_path):
    img = np.full((120, 160, 3), 80, np.uint8)
    for x in range(10, 150, 22):
        cv2.line(img, (x, 5), (x + 4, 115), (240, 240, 240), 2)
    for y in range(10, 110, 20):
        cv2.line(img, (5, y), (155, y + 6), (200, 200, 200), 2)
    path = tmp_path / "scene.png"
    cv2.imwrite(str(path), img)
    return path


def test_calibrate_prints_one_json_object_per_image(photo, capsys):
    assert main(["calibrate", str(photo), str(photo)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2
    record = json.loads(lines[0])
    assert record["image"] == str(photo)
    for key in ("K", "R", "focal", "fov_v", "fov_h", "pitch", "roll", "zenith", "horizon", "vps"):
        assert key in record


def _floats(value):
    if isinstance(value, float):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _floats(item)
    elif isinstance(value, list):
        for item in value:
            yield from _floats(item)


def test_piped_output_is_json_lines_with_six_significant_digits(photo):
    # one long line with float noise (660.2574462890625) once; rounded at output, the result keeps every digit
    run = subprocess.run([sys.executable, "-m", "ngp_kornia.cli", "calibrate", str(photo), str(photo)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    rows = [json.loads(line) for line in run.stdout.splitlines()]
    floats = list(_floats(rows))
    assert len(rows) == 2 and len(floats) > 40
    assert all(float(f"{v:.6g}") == v for v in floats)
    assert any(float(f"{v:.5g}") != v for v in floats)  # six digits, not fewer


def test_a_terminal_gets_a_short_table_and_json_on_request(photo, tmp_path, capsys, monkeypatch):
    noise = tmp_path / "noise.png"
    cv2.imwrite(str(noise), np.random.default_rng(1).integers(0, 256, (120, 160, 3), dtype=np.uint8))
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert main(["calibrate", str(photo), str(noise)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and lines[0].split()[1:] == [
        "focal", "px", "FoV", "v", "deg", "pitch", "deg", "roll", "deg", "confidence", "warning"]
    assert lines[1].split()[0].endswith("scene.png") and len(lines[1].split()) >= 6  # a long path keeps its end
    assert lines[2].endswith("0.00  no camera found (valid false)")
    assert main(["calibrate", str(photo), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["image"] == str(photo)


def test_bad_image_is_one_line_on_stderr_and_the_rest_still_run(photo, tmp_path, capsys):
    missing = tmp_path / "missing.jpg"
    code = main(["calibrate", str(missing), str(photo)])
    out, err = capsys.readouterr()
    assert code == 1
    assert len(out.strip().splitlines()) == 1 and json.loads(out)["image"] == str(photo)
    assert err.strip().count("\n") == 0 and "missing.jpg: file not found" in err


def test_overlay_is_written_as_an_image(photo, tmp_path, capsys):
    target = tmp_path / "out" / "overlay.png"
    assert main(["calibrate", str(photo), "--overlay", str(target)]) == 0
    drawn = cv2.imread(str(target))
    assert drawn is not None and drawn.shape[1:] == (160, 3) and drawn.shape[0] > 120  # the key strip below


def test_overlay_folder_for_several_images(photo, tmp_path, capsys):
    second = tmp_path / "second.png"
    second.write_bytes(photo.read_bytes())
    assert main(["calibrate", str(photo), str(second), "--overlay", str(tmp_path / "ov")]) == 0
    assert sorted(p.name for p in (tmp_path / "ov").iterdir()) == ["scene_overlay.png", "second_overlay.png"]


def test_installed_command_reports_errors_without_traceback(tmp_path):
    bad = tmp_path / "bad.jpg"
    bad.write_text("not an image")
    run = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", str(bad)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 1
    assert (
        "Traceback" not in run.stderr
        and run.stderr.strip()
        == f"ngp: error: {bad}: not a readable image (supported: JPEG, PNG, TIFF, BMP, WebP, ...)"
    )


def test_demo_prints_estimate_next_to_truth(tmp_path, capsys):
    overlay = tmp_path / "demo.png"
    assert main(["demo", "--overlay", str(overlay)]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: [float(v) for v in line.split()[1:]] for line in out.splitlines()[2:7]}
    assert set(rows) == {"focal", "fov_v", "fov_h", "pitch", "roll"}
    assert abs(rows["pitch"][0] - rows["pitch"][1]) < 1.0 and abs(rows["roll"][0] - rows["roll"][1]) < 1.0
    assert abs(rows["fov_v"][0] - rows["fov_v"][1]) < 3.0
    assert cv2.imread(str(overlay)) is not None


def test_render_writes_images_and_ground_truth(tmp_path, capsys):
    assert main(["render", str(tmp_path / "r"), "--count", "2", "--seed", "5", "--size", "160x120"]) == 0
    records = json.loads((tmp_path / "r" / "ground_truth.json").read_text())
    assert len(records) == 2
    image = cv2.imread(str(tmp_path / "r" / records[0]["image"]))
    assert image.shape == (120, 160, 3)
    for key in ("K", "R", "focal", "fov_v", "fov_h", "pitch", "roll", "zenith", "horizon", "vps"):
        assert key in records[0]


def test_render_config_file_renders_what_render_scene_gives_with_it(tmp_path, capsys):
    from ngp_kornia.training.synth.render import render_scene
    from ngp_kornia.training.synth.render_config import RenderConfig

    settings = {"stairs": 2.0, "fronto_prob": 1.0, "pitch": [30, 40], "kinds": {"street": 1.0}}
    (tmp_path / "hard.json").write_text(json.dumps(settings))
    args = ["render", str(tmp_path / "r"), "--count", "1", "--size", "160x120", "--config", str(tmp_path / "hard.json")]
    assert main(args) == 0
    record = json.loads((tmp_path / "r" / "ground_truth.json").read_text())[0]
    assert 30.0 <= record["pitch"] <= 40.0
    expected = render_scene(record["seed"], (160, 120), RenderConfig(**settings)).image
    written = cv2.cvtColor(cv2.imread(str(tmp_path / "r" / record["image"])), cv2.COLOR_BGR2RGB)
    assert np.array_equal(written, expected)


@pytest.mark.parametrize(
    "text, message",
    [("{\"stair\": 1}", "unknown settings ['stair']"), ("[1, 2]", "JSON object"), ("{", "not a readable JSON file"),
     ("{\"pitch\": [50, 10]}", "pitch must be a (min, max) range")],
)
def test_render_bad_config_is_a_usage_error(tmp_path, capsys, text, message):
    (tmp_path / "c.json").write_text(text)
    assert main(["render", str(tmp_path / "r"), "--config", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ngp: error: --config ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "option",
    [["--size", "big"], ["--size", "0x480"], ["--size", "10x10"], ["--size", "100000x100000"], ["--count", "0"]],
)
def test_render_rejects_a_bad_size_or_count(tmp_path, capsys, option):
    with pytest.raises(SystemExit) as exit_info:
        main(["render", str(tmp_path / "r"), *option])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and f"ngp render: error: argument {option[0]}: " in err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "setting", ['{"stairs": NaN}', '{"billboards": NaN}', '{"clutter": Infinity}', '{"stairs": true}',
                '{"pitch": [-10, NaN]}', '{"kinds": {"street": NaN}}'],
)
def test_render_config_refuses_numbers_that_are_not_finite(tmp_path, capsys, setting):
    # NaN passes every range check (each comparison is false), true would count as 1: all refused by name
    (tmp_path / "c.json").write_text(setting)
    assert main(["render", str(tmp_path / "r"), "--config", str(tmp_path / "c.json"), "--count", "1"]) == 2
    err = capsys.readouterr().err
    name = next(iter(json.loads(setting)))
    assert err.startswith(f"ngp: error: --config {tmp_path / 'c.json'}: {name} must hold finite numbers")
    assert err.count("\n") == 1 and not (tmp_path / "r").exists()


@pytest.mark.parametrize("mode", ["level", "upright", "frontal"])
def test_rectify_writes_a_png(photo, tmp_path, capsys, mode):
    target = tmp_path / "out" / f"{mode}.png"
    assert main(["rectify", str(photo), "--mode", mode, "-o", str(target), "--crop", "valid"]) == 0
    written = cv2.imread(str(target))
    assert written is not None and written.ndim == 3 and min(written.shape[:2]) > 10
    assert str(target) in capsys.readouterr().out


def test_rectify_keep_of_a_rendered_scene_keeps_the_pixels(tmp_path, capsys):
    from ngp_kornia.training.synth.render import render_scene

    source = tmp_path / "scene.png"
    cv2.imwrite(str(source), cv2.cvtColor(render_scene(1, (320, 240)).image, cv2.COLOR_RGB2BGR))
    target = tmp_path / "upright.png"
    assert main(["rectify", str(source), "-o", str(target)]) == 0
    written = cv2.imread(str(target))
    assert written.shape[0] * written.shape[1] > 320 * 240  # the tilted frame needs a larger canvas


def test_rectify_refuses_an_invalid_answer_unless_forced(tmp_path, capsys):
    noise = tmp_path / "noise.png"  # no lines of structure: the answer is a guess (it was once written, exit 0)
    cv2.imwrite(str(noise), np.random.default_rng(1).integers(0, 256, (480, 640, 3), dtype=np.uint8))
    target = tmp_path / "out.png"
    assert main(["rectify", str(noise), "-o", str(target)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no camera found (valid false" in err and "--force-invalid" in err
    assert not target.exists()
    assert main(["rectify", str(noise), "-o", str(target), "--force-invalid"]) == 0
    assert np.array_equal(cv2.imread(str(target)), cv2.imread(str(noise)))  # a level camera: the image as it is


def test_rectify_rejects_a_bad_mode(photo, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["rectify", str(photo), "--mode", "sideways", "-o", str(tmp_path / "x.png")])
    assert exit_info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_rectify_missing_input_is_one_line_on_stderr(tmp_path, capsys):
    missing = tmp_path / "missing.jpg"
    assert main(["rectify", str(missing), "-o", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and err.startswith("ngp: error: ") and "missing.jpg: file not found" in err
    assert not (tmp_path / "x.png").exists()


def test_output_cut_short_stops_quietly(photo):
    # `ngp calibrate *.jpg | head -c 20`: the closed pipe is not reported as a failure of the images
    proc = subprocess.Popen(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", *[str(photo)] * 20],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.read(20)
    proc.stdout.close()
    assert proc.wait(timeout=120) == 141
    assert b"error" not in proc.stderr.read()


def _one_error_line(err):
    return err.count("\n") == 1 and err.startswith("ngp: error: ") and "Traceback" not in err


def test_overlay_path_without_extension_is_one_line(photo, tmp_path, capsys):
    assert main(["calibrate", str(photo), "--overlay", str(tmp_path / "overlay")]) == 1
    out, err = capsys.readouterr()
    assert _one_error_line(err) and "end the name with .png or .jpg" in err and out == ""


def test_existing_outputs_need_force(photo, tmp_path, capsys):
    target = tmp_path / "overlay.png"
    target.write_bytes(b"keep me")
    assert main(["calibrate", str(photo), "--overlay", str(target)]) == 1
    assert "exists; add --force" in capsys.readouterr().err and target.read_bytes() == b"keep me"
    assert main(["calibrate", str(photo), "--overlay", str(target), "--force"]) == 0
    assert cv2.imread(str(target)) is not None
    rectified = tmp_path / "upright.png"
    rectified.write_bytes(b"keep me")
    assert main(["rectify", str(photo), "-o", str(rectified)]) == 1
    assert "exists; add --force" in capsys.readouterr().err and rectified.read_bytes() == b"keep me"
    assert main(["rectify", str(photo), "-o", str(rectified), "--force"]) == 0


def test_an_input_is_never_overwritten_even_with_force(photo, capsys):
    before = photo.read_bytes()
    assert main(["calibrate", str(photo), "--overlay", str(photo), "--force"]) == 1
    assert main(["rectify", str(photo), "-o", str(photo), "--force"]) == 1
    err = capsys.readouterr().err
    assert err.count("is one of the input images") == 2 and photo.read_bytes() == before


def test_a_hard_link_of_an_input_is_the_input(photo, capsys):
    link = photo.parent / "link.png"
    link.hardlink_to(photo)
    before = photo.read_bytes()
    assert main(["rectify", str(photo), "-o", str(link), "--force"]) == 1
    assert "is one of the input images" in capsys.readouterr().err and photo.read_bytes() == before


def test_overlays_of_several_images_never_replace_each_other(photo, tmp_path, capsys):
    for folder in ("one", "two"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "same.png").write_bytes(photo.read_bytes())
    same = [str(tmp_path / "one" / "same.png"), str(tmp_path / "two" / "same.png")]
    assert main(["calibrate", *same, "--overlay", str(tmp_path / "overlays")]) == 1
    assert "would both write" in capsys.readouterr().err and not (tmp_path / "overlays").exists()
    assert main(["calibrate", same[0], str(photo), "--overlay", str(tmp_path / "one.png")]) == 1
    assert "names a file, but 2 images were given" in capsys.readouterr().err
    assert not (tmp_path / "one.png").exists()


def test_the_render_size_limits_are_those_of_the_image_reader():
    from ngp_kornia import cli_render, io

    assert (cli_render.MIN_SIDE, cli_render.MAX_PIXELS) == (io.MIN_SIZE, io.MAX_PIXELS)


def test_render_into_a_dataset_needs_force(tmp_path, capsys):
    assert main(["render", str(tmp_path / "set"), "--count", "1", "--size", "64x48"]) == 0
    truth = (tmp_path / "set" / "ground_truth.json").read_text()
    assert main(["render", str(tmp_path / "set"), "--count", "1", "--size", "64x48", "--seed", "5"]) == 1
    err = capsys.readouterr().err
    assert _one_error_line(err) and "is not empty; add --force" in err
    assert (tmp_path / "set" / "ground_truth.json").read_text() == truth
    assert main(["render", str(tmp_path / "set"), "--count", "1", "--size", "64x48", "--seed", "5", "--force"]) == 0


def test_exif_orientation_is_applied_and_reported(tmp_path, capsys):
    stored = np.zeros((80, 120, 3), np.uint8)
    path = tmp_path / "phone.jpg"
    path.write_bytes(jpeg_with_orientation(stored, 8))
    assert main(["calibrate", str(path)]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["exif_orientation"] == 8 and (record["height"], record["width"]) == (120, 80)


def test_libpng_noise_does_not_reach_stderr(tmp_path):
    png = cv2.imencode(".png", np.zeros((64, 64, 3), np.uint8))[1].tobytes()
    bad = bytearray(png)
    bad[len(bad) // 2] ^= 0xFF
    path = tmp_path / "crc.png"
    path.write_bytes(bytes(bad))
    run = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "calibrate", str(path)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 1 and _one_error_line(run.stderr) and run.stderr.startswith(f"ngp: error: {path}")


def test_overlay_draws_the_segments_the_calibration_saw(tmp_path, monkeypatch, capsys):
    import ngp_kornia.viz
    from ngp_kornia.pipeline import SegmentSettings
    from ngp_kornia.pipeline.segments import detect_segments, detect_segments_gray
    from ngp_kornia.training.synth.render import render_scene

    rgb = render_scene(2).image  # 640x480, more segments than the parser keeps
    path = tmp_path / "scene.png"
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert len(detect_segments_gray(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), SegmentSettings(max_segments=4096))) > 512
    drawn = []
    draw = ngp_kornia.viz.draw_calibration
    def spy(image, calibration, segments, **options):
        drawn.append(segments)
        return draw(image, calibration, segments, **options)

    monkeypatch.setattr(ngp_kornia.viz, "draw_calibration", spy)
    assert main(["calibrate", str(path), "--overlay", str(tmp_path / "overlay.png")]) == 0
    expected, mask = detect_segments(rgb)
    assert len(drawn) == 1 and drawn[0].shape == (SegmentSettings().max_segments, 2, 2)
    np.testing.assert_array_equal(drawn[0], expected[0][mask[0]].numpy())


def test_kornia_check_errors_are_one_line(photo, monkeypatch, capsys):
    from kornia.core.check import KORNIA_CHECK

    import ngp_kornia.api

    def failing(*args, **kwargs):
        KORNIA_CHECK(False, "a check inside kornia failed")  # raises kornia's BaseError, not a ValueError

    monkeypatch.setattr(ngp_kornia.api, "calibrate", failing)
    assert main(["calibrate", str(photo)]) == 1
    err = capsys.readouterr().err
    assert _one_error_line(err) and "a check inside kornia failed" in err


@pytest.mark.parametrize(("entry", "args"), [("ngp", ["calibrate"]), ("ngp_train", ["fit", "--config", "zsnet"])])
def test_ctrl_c_during_start_up_ends_with_a_message(entry, args, photo, tmp_path):
    # the commands import torch, OpenCV and Lightning first (seconds): Ctrl+C then is answered as during their work.
    # The child says when it starts those imports, so the interrupt lands in them however fast the machine is (the
    # arguments were parsed and checked before, without them).
    import signal

    code = (
        "import importlib, sys\n"
        "real = importlib.import_module\n"
        "def announced(name, *rest):\n"
        "    if name in ('ngp_kornia.api', 'lightning.pytorch.cli'):\n"
        "        print('importing', flush=True)\n"
        "    return real(name, *rest)\n"
        "importlib.import_module = announced\n"
        f"from ngp_kornia._launch import {entry}\n"
        f"sys.exit({entry}())\n"
    )
    pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, "cwd": tmp_path}
    args = [*args, str(photo)] if entry == "ngp" else args  # an image that exists: the command goes on to import
    process = subprocess.Popen([sys.executable, "-c", code, *args], **pipes)
    assert process.stdout.readline() == "importing\n"
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    assert "Traceback" not in err and err.strip().endswith("interrupted")


def _turned_render(tmp_path):
    from ngp_kornia.training.synth.render import render_scene

    path = tmp_path / "turned.png"
    image = render_scene(2_500_029, (320, 240)).image  # turned by 90, read so with probability 0.99
    cv2.imwrite(str(path), cv2.cvtColor(np.rot90(image).copy(), cv2.COLOR_RGB2BGR))
    return path


def test_a_doubted_photo_is_warned_about_with_its_upright_probability(tmp_path, capsys):
    path = _turned_render(tmp_path)
    assert main(["calibrate", str(path)]) == 0
    out = capsys.readouterr()
    answer = json.loads(out.out)
    assert answer["turned"] == 90
    assert out.err.startswith(f"ngp: warning: {path}: upright probability {answer['upright']:.2f}, looks turned by")
    assert out.err.count("\n") == 1
    assert main(["calibrate", str(path), "--upright.sure", "1", "--upright.doubt", "1"]) == 0  # doubted, no turn
    err = capsys.readouterr().err
    assert err.startswith(f"ngp: warning: {path}: upright probability") and "(below 1)" in err
    assert main(["calibrate", str(path), "--upright.sure", "1", "--upright.doubt", "0"]) == 0  # nothing doubted
    assert capsys.readouterr().err == ""


def test_rectify_refuses_a_doubted_photo_unless_allowed(tmp_path, capsys):
    path, target = _turned_render(tmp_path), tmp_path / "straight.png"
    assert main(["rectify", str(path), "-o", str(target), "--upright.doubt", "1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"ngp: error: {path}: upright probability")
    assert err.endswith("add --allow-turned to rectify it as read\n") and err.count("\n") == 1
    assert not target.exists()
    assert main(["rectify", str(path), "-o", str(target), "--upright.doubt", "1", "--allow-turned"]) == 0
    assert cv2.imread(str(target)) is not None
