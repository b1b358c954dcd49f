"""ngp predict: a JSON line for every file of a folder (error rows for unreadable ones), the same answer as
calibrate(), and every image exactly once when several processes share the work."""

import json
import os
import subprocess
import sys

import cv2
import pytest

from ngp_kornia import calibrate
from ngp_kornia.cli import main
from ngp_kornia.predict import merge_parts, predict_folder
from ngp_kornia.rows import result_row
from ngp_kornia.training.synth.render import render_scene

#: an earlier run's results in the file a run replaces
OLD_RESULTS = '{"image": "earlier.png", "error": "an earlier run"}\n'


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
    assert counts == {"images": 7, "errors": 2, "interrupted": False, "rank": 0}
    errors = {row["image"]: row["error"] for row in rows if "error" in row}
    assert set(errors) == {"corrupt.png", "empty.jpg"} and "file is empty" in errors["empty.jpg"]
    for row in rows:
        assert ("error" in row) != ("focal" in row)


def test_a_row_is_what_calibrate_gives_for_the_file(folder, predicted):
    row = next(r for r in predicted[1] if r["image"] == "scene02.png")
    expected = json.loads(json.dumps(result_row("scene02.png", calibrate(str(folder / "scene02.png")))))
    assert row == expected


def test_a_row_is_what_ngp_calibrate_json_prints_for_the_file(folder, predicted, capsys):
    row = next(r for r in predicted[1] if r["image"] == "scene03.png")
    assert main(["calibrate", str(folder / "scene03.png"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == {**row, "image": str(folder / "scene03.png")}


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


_SESSION = """
import json, sys
import cv2, numpy as np
from ngp_kornia.predict import predict_folder
cv2.setNumThreads(2)  # a session that has used OpenCV's worker threads before the fork
cv2.resize(np.zeros((2000, 2000, 3), np.uint8), (1000, 1000), interpolation=cv2.INTER_AREA)
print(json.dumps(predict_folder(sys.argv[1], sys.argv[2], devices=2, recursive=True)))
"""


@pytest.mark.slow
def test_two_processes_from_a_python_session_give_the_rows_of_one(folder, predicted, tmp_path):
    # the processes are forked from the calling one: the call works in a running session (a notebook, a script
    # that has used OpenCV's threads) and returns the merged counts
    if sys.platform == "win32":
        pytest.skip("no fork on Windows")
    out = tmp_path / "two.jsonl"
    run = subprocess.run(
        [sys.executable, "-c", _SESSION, str(folder), str(out)], capture_output=True, text=True, timeout=240
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == predicted[0] and _rows(out) == predicted[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.jsonl"]  # no part or temporary file left


def test_out_that_is_an_input_is_refused(tmp_path, capsys):
    folder = tmp_path / "photos"
    _write_scenes(folder, [0])
    image = folder / "scene00.png"
    before = image.read_bytes()
    assert main(["predict", str(folder), "--out", str(image)]) == 1
    err = capsys.readouterr().err
    assert "is one of the input images" in err and err.count("\n") == 1 and image.read_bytes() == before


def test_out_that_would_lose_a_file_of_the_users_is_refused(tmp_path, capsys):
    folder = tmp_path / "photos"
    _write_scenes(folder, [0])
    notes = tmp_path / "notes.txt"
    notes.write_text("precious\n")
    (tmp_path / "hard.png").hardlink_to(folder / "scene00.png")
    for out, message in ((notes, "holds no rows of ngp predict"), (tmp_path / "hard.png", "one of the input images")):
        assert main(["predict", str(folder), "-o", str(out)]) == 1
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
    assert notes.read_text() == "precious\n"
    if os.path.exists("/dev/null"):
        assert main(["predict", str(folder), "-o", "/dev/null"]) == 1
        assert "not a regular file" in capsys.readouterr().err and os.path.exists("/dev/null")


def test_out_that_is_a_link_gets_the_rows_in_the_file_it_links_to(tmp_path):
    folder = tmp_path / "photos"
    _write_scenes(folder, [0])
    (tmp_path / "runs").mkdir()
    real = tmp_path / "runs" / "real.jsonl"
    real.write_text('{"image": "earlier run"}\n')
    link = tmp_path / "latest.jsonl"
    link.symlink_to(real)
    assert main(["predict", str(folder), "--out", str(link)]) == 0
    assert link.is_symlink() and [row["image"] for row in _rows(real)] == ["scene00.png"]


def test_unrelated_part_files_and_the_old_results_survive_until_the_end(tmp_path, monkeypatch):
    from ngp_kornia import predict as predict_module

    folder = tmp_path / "photos"
    _write_scenes(folder, [0, 1])
    out = tmp_path / "results.jsonl"
    out.write_text(OLD_RESULTS)
    unrelated = tmp_path / "results.jsonl.rank0"
    unrelated.write_text("someone else's file\n")
    seen = []
    original = predict_module.FolderPredictor.calibrate

    def spy(self, image, *rest):
        seen.append(out.read_text())  # mid-run: out still holds the old results, never a half-written file
        return original(self, image, *rest)

    monkeypatch.setattr(predict_module.FolderPredictor, "calibrate", spy)
    predict_folder(folder, out)
    assert seen == [OLD_RESULTS] * 2 and len(_rows(out)) == 2
    assert unrelated.read_text() == "someone else's file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos", "results.jsonl", "results.jsonl.rank0"]


def test_any_failure_of_one_image_is_its_row(tmp_path, monkeypatch):
    from ngp_kornia import folder_items
    from ngp_kornia import predict as predict_module
    from tests.image_files import png_declaring

    folder = tmp_path / "photos"
    _write_scenes(folder, [0, 1, 2])
    (folder / "bomb.png").write_bytes(png_declaring(30000, 30000))
    read = folder_items.read_rgb_oriented

    def flaky_read(path):
        if path.name == "scene01.png":
            raise MemoryError("no memory left for this one")
        return read(path)

    original = predict_module.FolderPredictor.calibrate
    calls = []

    def flaky_calibrate(self, image, *rest):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("something unexpected inside the parser")
        return original(self, image, *rest)

    monkeypatch.setattr(folder_items, "read_rgb_oriented", flaky_read)
    monkeypatch.setattr(predict_module.FolderPredictor, "calibrate", flaky_calibrate)
    counts = predict_folder(folder, tmp_path / "r.jsonl")
    rows = {r["image"]: r for r in _rows(tmp_path / "r.jsonl")}
    assert counts["images"] == 4 and counts["errors"] == 3
    assert "over the limit" in rows["bomb.png"]["error"]
    assert "MemoryError: no memory left" in rows["scene01.png"]["error"]
    assert "RuntimeError: something unexpected" in rows["scene02.png"]["error"]
    assert "focal" in rows["scene00.png"]


def test_rows_report_the_exif_orientation(tmp_path):
    from tests.image_files import jpeg_with_orientation

    folder = tmp_path / "photos"
    folder.mkdir()
    stored = render_scene(0, size=(160, 120)).image
    (folder / "phone.jpg").write_bytes(jpeg_with_orientation(stored, 6))
    predict_folder(folder, tmp_path / "r.jsonl")
    (row,) = _rows(tmp_path / "r.jsonl")
    assert row["exif_orientation"] == 6 and (row["height"], row["width"]) == (160, 120)
    assert row == result_row("phone.jpg", calibrate(folder / "phone.jpg"))


def test_devices_are_capped_at_the_usable_cores(monkeypatch, folder, tmp_path, capsys):
    import ngp_kornia.predict as predict

    monkeypatch.setattr(predict, "usable_cores", lambda: 1)
    with pytest.warns(UserWarning, match="devices=100 is more than the 1 CPU cores"):
        assert predict.cap_devices(100) == 1
    assert predict.cap_devices(1) == 1
    out = tmp_path / "r.jsonl"
    assert main(["predict", str(folder / "sub"), "--out", str(out), "--devices", "100"]) == 0
    err = capsys.readouterr().err
    assert err == "ngp: warning: --devices 100 capped at 1, the CPU cores available\n"
    assert len(_rows(out)) == 1


def test_usable_cores_is_at_most_the_core_count():
    from ngp_kornia.predict import usable_cores

    assert 1 <= usable_cores() <= (os.cpu_count() or 1)


def test_predict_keeps_the_callers_thread_count(folder, tmp_path):
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        predict_folder(folder / "sub", tmp_path / "r.jsonl")
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="this machine has a GPU")
def test_accelerator_gpu_without_a_gpu_is_one_line_and_a_usage_error(folder, tmp_path, capsys):
    out = tmp_path / "r.jsonl"
    assert main(["predict", str(folder / "sub"), "--out", str(out), "--accelerator", "gpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ngp: error: --accelerator gpu: this machine has no GPU") and err.count("\n") == 1
    assert "--accelerator cpu" in err and not out.exists()


def test_a_progress_bar_on_a_terminal_with_the_rate_and_the_time_left(folder, tmp_path):
    # stderr on a terminal (a pseudo-terminal of 100 columns), stdout in a pipe: the bar goes to stderr only
    import fcntl
    import pty
    import struct
    import termios

    primary, secondary = pty.openpty()
    fcntl.ioctl(secondary, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(tmp_path / "r.jsonl")]
    run = subprocess.run(command, stdout=subprocess.PIPE, stderr=secondary, text=True, timeout=240)
    os.close(secondary)
    shown = b""
    while chunk := _read_some(primary):
        shown += chunk
    os.close(primary)
    last = shown.decode(errors="replace").replace("\r", "\n").split("ngp predict: 100%")[-1]
    assert run.returncode == 1 and run.stdout.strip() == f"6 rows written to {tmp_path / 'r.jsonl'}"
    assert "6/6 [" in last and "image/s]" in last and "<00:00" in last, shown[-500:]  # done, time left, rate


def _read_some(fd) -> bytes:
    import select

    if not select.select([fd], [], [], 1)[0]:
        return b""
    try:
        return os.read(fd, 1 << 16)
    except OSError:  # the other end is closed: all was read
        return b""
