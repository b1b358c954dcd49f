"""ngp predict: a JSON line for every file of a folder (error rows for unreadable ones), the same answer as
calibrate(), and every image exactly once when several processes share the work."""

import json
import subprocess
import sys

import cv2
import pytest

from ngp_kornia import calibrate
from ngp_kornia.cli import main
from ngp_kornia.data.synth.render import render_scene
from ngp_kornia.predict import merge_parts, predict_folder


def _write_scenes(folder, seeds):
    folder.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        image = render_scene(seed, size=(160, 120)).image
        cv2.imwrite(str(folder / f"scene{seed:02d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("photos")
    _write_scenes(root, range(4))
    _write_scenes(root / "sub", [4])
    (root / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a picture IEND")
    (root / "empty.jpg").write_bytes(b"")
    (root / "notes.txt").write_text("not an image extension: not listed")
    return root


@pytest.fixture(scope="module")
def predicted(folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "results.jsonl"
    counts = predict_folder(folder, out, recursive=True)
    return counts, _rows(out)


def test_a_row_for_every_file_and_error_rows_for_the_bad_ones(predicted):
    counts, rows = predicted
    names = [row["image"] for row in rows]
    expected = ["corrupt.png", "empty.jpg", "scene00.png", "scene01.png", "scene02.png", "scene03.png"]
    assert names == [*expected, "sub/scene04.png"]
    assert counts == {"images": 7, "errors": 2}
    errors = {row["image"]: row["error"] for row in rows if "error" in row}
    assert set(errors) == {"corrupt.png", "empty.jpg"} and "file is empty" in errors["empty.jpg"]
    for row in rows:
        assert ("error" in row) != ("focal" in row)


def test_a_row_is_what_calibrate_gives_for_the_file(folder, predicted):
    row = next(r for r in predicted[1] if r["image"] == "scene02.png")
    expected = json.loads(json.dumps(calibrate(str(folder / "scene02.png")).to_dict()))
    assert row == {"image": "scene02.png", **expected}


def test_merge_keeps_dataset_order_and_drops_padded_duplicates(tmp_path):
    # two ranks, the second padded with a copy of index 0 as a repeating distributed sampler does
    (tmp_path / "p0").write_text('0\t{"image": "a"}\n2\t{"image": "c"}\n4\t{"image": "e"}\n')
    (tmp_path / "p1").write_text('0\t{"image": "a"}\n1\t{"image": "b"}\n3\t{"image": "d"}\n')
    assert merge_parts([tmp_path / "p0", tmp_path / "p1"], tmp_path / "out.jsonl") == 5
    assert [r["image"] for r in _rows(tmp_path / "out.jsonl")] == ["a", "b", "c", "d", "e"]


def test_cli_reports_the_bad_files_on_one_line(folder, tmp_path, capsys):
    out = tmp_path / "r.jsonl"
    assert main(["predict", str(folder), "--out", str(out)]) == 1  # not recursive: sub/ is left out
    captured = capsys.readouterr()
    assert "6 rows written" in captured.out and len(_rows(out)) == 6
    assert captured.err.strip() == f'ngp: error: 2 of 6 images could not be read; see the rows with "error" in {out}'


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing"], "no such folder"),
        (["file.png"], "is a file, not a folder; for single images use ngp calibrate"),
        (["empty"], "no images found"),
        (["empty", "--devices", "0"], "--devices must be at least 1"),
    ],
)
def test_cli_bad_input_is_one_line_naming_the_problem(tmp_path, capsys, args, message):
    (tmp_path / "empty").mkdir()
    (tmp_path / "file.png").write_bytes(b"")
    code = main(["predict", str(tmp_path / args[0]), *args[1:], "--out", str(tmp_path / "r.jsonl")])
    err = capsys.readouterr().err
    assert code in (1, 2) and err.startswith("ngp: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "r.jsonl").exists()


@pytest.mark.slow
def test_two_processes_write_every_image_exactly_once(tmp_path):
    folder = tmp_path / "photos"
    _write_scenes(folder, range(10))
    (folder / "zz_corrupt.jpg").write_bytes(b"\xff\xd8 not a jpeg")  # 11 files: the ranks get 6 and 5
    out = tmp_path / "results.jsonl"
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out), "--devices", "2"]
    run = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr  # 1: the corrupt file
    rows = _rows(out)
    assert [r["image"] for r in rows] == [f"scene{s:02d}.png" for s in range(10)] + ["zz_corrupt.jpg"]
    assert "error" in rows[-1] and all("focal" in r for r in rows[:-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos", "results.jsonl"]  # the part files are gone
    assert "11 rows written" in run.stdout and "Traceback" not in run.stderr
