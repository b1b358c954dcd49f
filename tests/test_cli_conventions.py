"""The ngp command's conventions: --version, defaults in every --help, usage errors once with exit 2, the list API
behind several images, frontal rectification, render's progress bar on terminals only."""

import argparse
import json

import cv2
import pytest

import ngp_kornia
from ngp_kornia import calibrate, cli
from ngp_kornia.cli_options import HelpAllAction
from ngp_kornia.rows import result_row
from ngp_kornia.training.synth.render import render_scene


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scenes")
    paths = []
    for seed, size in ((1, (320, 240)), (4, (256, 256)), (6, (240, 320))):
        path = folder / f"scene{seed}.png"
        cv2.imwrite(str(path), cv2.cvtColor(render_scene(seed, size).image, cv2.COLOR_RGB2BGR))
        paths.append(path)
    return paths


def _subparsers(parser):
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"ngp {ngp_kornia.__version__}"


def test_every_help_shows_the_defaults_and_describes_every_argument():
    parser = cli._parser()
    for name, sub in _subparsers(parser).items():
        for action in sub._actions:  # as --help-all shows them: the pipeline settings too
            action.help = getattr(action, "full_help", action.help)
        text = " ".join(sub.format_help().split())
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, HelpAllAction)):
                continue
            assert action.help, f"ngp {name}: {action.dest} has no help"
            if action.default not in (None, False) and action.option_strings:
                assert f"(default: {action.default})" in text, f"ngp {name} --help: no default for {action.dest}"


def test_render_help_describes_its_arguments(capsys):
    with pytest.raises(SystemExit):
        cli.main(["render", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "number of scenes (default: 16)" in out and "ground_truth.json" in out and "(default: 640x480)" in out


@pytest.mark.parametrize("weights", ["bogus", "missing.pt"])
@pytest.mark.parametrize("command", ["calibrate", "rectify", "predict"])
def test_bad_weights_is_one_usage_error_with_exit_2(tmp_path, capsys, scenes, weights, command):
    tail = {
        "calibrate": [str(scenes[0]), str(tmp_path / "missing.jpg"), str(scenes[1])],
        "rectify": [str(scenes[0]), "-o", str(tmp_path / "out.png")],
        "predict": [str(scenes[0].parent), "--out", str(tmp_path / "rows.jsonl")],
    }[command]
    with pytest.raises(SystemExit) as exit_info:
        cli.main([command, *tail, "--weights", str(tmp_path / weights) if weights.endswith(".pt") else weights])
    out, err = capsys.readouterr()
    assert exit_info.value.code == 2 and out == ""
    errors = [line for line in err.splitlines() if "error" in line]
    assert len(errors) == 1 and errors[0].startswith(f"ngp {command}: error: --weights: ")
    assert "missing.jpg" not in err  # reported before any image is read
    assert not (tmp_path / "out.png").exists() and not (tmp_path / "rows.jsonl").exists()


def test_several_images_give_what_the_list_api_gives(scenes, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "_CHUNK", 2)  # several chunks, one of them with an unreadable file
    images = [str(scenes[0]), str(tmp_path / "missing.jpg"), str(scenes[1]), str(scenes[2])]
    assert cli.main(["calibrate", *images, "--weights", "none"]) == 1
    out, err = capsys.readouterr()
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["image"] for r in rows] == [str(p) for p in scenes]
    expected = calibrate([str(p) for p in scenes], weights="none")
    for row, cal in zip(rows, expected, strict=True):
        assert row == json.loads(json.dumps(result_row(row["image"], cal)))
    errors = [line for line in err.splitlines() if line.startswith("ngp: error:")]  # warnings may come beside
    assert len(errors) == 1 and "missing.jpg: file not found" in errors[0]


def test_frontal_rectification_works_with_the_default_crop(tmp_path, capsys):
    source = tmp_path / "scene.png"
    cv2.imwrite(str(source), cv2.cvtColor(render_scene(1, (640, 480)).image, cv2.COLOR_RGB2BGR))
    assert cli.main(["rectify", str(source), "--mode", "frontal", "-o", str(tmp_path / "front.png")]) == 0
    assert cv2.imread(str(tmp_path / "front.png")) is not None
    capsys.readouterr()
    # keeping every pixel of this oblique view is refused, and the message points at --crop valid
    assert cli.main(["rectify", str(source), "--mode", "frontal", "--crop", "keep", "-o", str(tmp_path / "k.png")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--crop valid" in err and not (tmp_path / "k.png").exists()


def test_render_shows_progress_on_a_terminal_only(tmp_path, capsys, monkeypatch):
    from ngp_kornia import cli_render

    monkeypatch.setattr(cli_render, "PROGRESS_DELAY", 0.0)
    assert cli.main(["render", str(tmp_path / "a"), "--count", "2", "--size", "96x64"]) == 0
    assert capsys.readouterr().err == ""  # not a terminal: no bar
    import sys

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert cli.main(["render", str(tmp_path / "b"), "--count", "2", "--size", "96x64"]) == 0
    err = capsys.readouterr().err
    assert "rendering" in err and "2/2" in err


def test_an_image_failing_inside_a_chunk_is_reported_and_the_others_still_print(scenes, capsys, monkeypatch):
    from ngp_kornia import api

    real = api.calibrate
    bad_shape = (256, 256, 3)  # scene4 is 256x256: make its calibration fail as a corrupt input would

    def flaky(image, **kwargs):
        if isinstance(image, list):
            return [flaky(item, **kwargs) for item in image]
        if getattr(image, "shape", None) == bad_shape:
            raise ValueError("cannot calibrate this one")
        return real(image, **kwargs)

    monkeypatch.setattr(api, "calibrate", flaky)
    assert cli.main(["calibrate", *map(str, scenes), "--weights", "none"]) == 1
    out, err = capsys.readouterr()
    assert [json.loads(line)["image"] for line in out.splitlines()] == [str(scenes[0]), str(scenes[2])]
    errors = [line for line in err.splitlines() if line.startswith("ngp: error:")]  # warnings may come beside
    assert errors == [f"ngp: error: {scenes[1]}: cannot calibrate this one"]


@pytest.mark.parametrize(
    "argv", [["calibrate", "--seed", "1e3", "x.png"], ["predict", "photos", "--seed", "x"], ["rectify"], ["calibrate"]]
)
def test_a_usage_error_is_the_short_usage_and_one_line(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    lines = capsys.readouterr().err.splitlines()
    assert stop.value.code == 2 and len(lines) == 2
    assert lines[0].startswith(f"usage: ngp {argv[0]} [options]") and lines[1].startswith(f"ngp {argv[0]}: error: ")


# --- help that fits a screen ------------------------------------------------------------------------------------

COMMANDS = ("calibrate", "predict", "rectify", "demo", "render")
#: what a --help for people never shows: equation numbers, Sphinx roles, reStructuredText literals, the paper's sets
MARKUP = ("Eq.", ":func:", ":class:", ":mod:", "``", "|L_z|", "|Z|")


def _help(capsys, *args) -> str:
    with pytest.raises(SystemExit) as stop:
        cli.main([*args])
    assert stop.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("command", ["", *COMMANDS])
def test_every_help_fits_a_screen_in_plain_words(command, capsys, monkeypatch):
    # calibrate --help was 264 lines of internals ("Eq. 22", |L_z|, :func:); every setting is under --help-all
    monkeypatch.setenv("COLUMNS", "80")
    text = _help(capsys, *([command] if command else []), "--help")
    assert len(text.splitlines()) <= 40, text
    assert not [word for word in MARKUP if word in text]
    assert "--segments.working_size 640" in text or command in ("", "demo", "render")


@pytest.mark.parametrize("command", ["calibrate", "predict", "rectify"])
def test_help_all_lists_every_setting_with_its_default(command, capsys, monkeypatch):
    from ngp_kornia.pipeline.settings import setting_fields

    monkeypatch.setenv("COLUMNS", "80")
    listed = _help(capsys, command, "--help")
    short = " ".join(listed.split())
    text = " ".join(_help(capsys, command, "--help-all").split())
    settings = list(setting_fields())
    assert len(settings) > 40 and all(f"--{stage}.{f.name}" in text for stage, f, _ in settings)
    assert not [line for line in listed.splitlines() if line.strip().startswith("--segments.")]
    assert text.count("(default: ") >= len(settings) and not [w for w in (":func:", "``") if w in text]
    assert short.split(" options: ")[1][:40] in text  # the everyday options too


def test_rectify_offers_only_what_makes_sense_for_one_image(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    text = _help(capsys, "rectify", "--help-all")
    assert "--same-camera" not in text and "--truth" not in text and "each folder" not in text
    assert "--force-invalid" in text and "--focal-35mm" in text
    assert "one camera per folder" in _help(capsys, "predict", "--help")


@pytest.mark.parametrize(("args", "hint"), [
    (["calibrate", "--focla", "3", "x.jpg"], "unrecognized option --focla: did you mean --focal?"),
    (["rectify", "x.jpg", "-o", "y.png", "--mdoe", "level"], "unrecognized option --mdoe: did you mean --mode?"),
    (["calibrate", "x.jpg", "--horizon.refnie", "false"], "did you mean --horizon.refine?"),
    (["predict", "a", "b", "-o", "r.jsonl"], "unrecognized arguments: b"),
])
def test_a_mistyped_option_gives_the_command_usage_and_the_closest_option(args, hint, capsys):
    # the top-level usage once, with "unrecognized arguments" and no hint
    with pytest.raises(SystemExit) as stop:
        cli.main(args)
    err = capsys.readouterr().err.splitlines()
    assert stop.value.code == 2 and len(err) == 2
    assert err[0].startswith(f"usage: ngp {args[0]} [options] ") and err[1].startswith(f"ngp {args[0]}: error: ")
    assert err[1].endswith(hint)
