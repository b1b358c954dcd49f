"""ngp predict --resume: a run killed outright (SIGKILL) at any point, its merge included, continued with --resume
ends with every row exactly once and the rows of a run that was never stopped; a resume of other images or other
options is refused; the rows files are read up to their last whole row."""

import json
import os
import signal
import subprocess
import sys
import time

import cv2
import pytest

from ngp_kornia.cli import main
from ngp_kornia.data.folder import ImageFolder
from ngp_kornia.data.image_list import ImageList
from ngp_kornia.predict import plan_run, predict_folder
from ngp_kornia.rowfiles import RunFolder, read_rows
from ngp_kornia.training.synth.render import render_scene

#: the run folder of results.jsonl
RUN = ".results.jsonl.ngp-run"


def _write_scenes(folder, seeds, size=(160, 120)):
    folder.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        image = render_scene(seed, size=size).image
        cv2.imwrite(str(folder / f"scene{seed:02d}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return folder


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Eight small scenes and a broken file, and the rows of a run that was never stopped."""
    folder = _write_scenes(tmp_path_factory.mktemp("photos"), range(8))
    (folder / "zz_broken.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    out = tmp_path_factory.mktemp("whole") / "rows.jsonl"
    predict_folder(folder, out)
    return folder, _rows(out)


def _rows_files(tmp_path):
    return sorted((tmp_path / RUN).glob("*.rows"))


def _leave_a_killed_run(folder, out, rows, done: list[int], torn: bool = True) -> None:
    """The run folder of a run of ``folder`` killed after the images ``done`` (``rows``: every image's row), its
    rows file ending in part of a row."""
    plan = plan_run(ImageList.from_folder(ImageFolder(folder)), out)
    run = RunFolder(out)
    run.start({**plan.state, "attempt": "0badc0de"}, keep=False)
    lines = "".join(f"{i}\t{json.dumps(rows[i])}\n" for i in done)
    tail = f'{len(rows) - 1}\t{{"image": "part of a row' if torn else ""
    run.rows_file("0badc0de", 0).write_text(lines + tail)


def _spy(monkeypatch) -> list:
    """The names of the images calibrated from now on."""
    from ngp_kornia import predict as predict_module

    calibrated = []
    original = predict_module.FolderPredictor.calibrate

    def spy(self, image, name=None, *rest):
        calibrated.append(name)
        return original(self, image, name, *rest)

    monkeypatch.setattr(predict_module.FolderPredictor, "calibrate", spy)
    return calibrated


def test_resume_calibrates_only_the_images_without_a_row(scenes, tmp_path, monkeypatch, capsys):
    folder, expected = scenes
    out = tmp_path / "results.jsonl"
    _leave_a_killed_run(folder, out, expected, done=[0, 1, 4])
    calibrated = _spy(monkeypatch)
    assert main(["predict", str(folder), "--out", str(out), "--resume"]) == 1  # 1: zz_broken.jpg
    captured = capsys.readouterr()
    assert captured.err.splitlines()[0] == f"ngp: resuming {out}: 3 of 9 images have their row; calibrating 6"
    assert calibrated == ["scene02.png", "scene03.png", "scene05.png", "scene06.png", "scene07.png"]
    assert _rows(out) == expected and "9 rows written" in captured.out
    assert _hidden(tmp_path) == []  # the run folder is gone with the run


def test_a_killed_merge_is_merged_again(scenes, tmp_path, monkeypatch):
    folder, expected = scenes
    out = tmp_path / "results.jsonl"
    _leave_a_killed_run(folder, out, expected, done=list(range(9)), torn=False)
    (tmp_path / RUN / "merged.1234abcd.tmp").write_text('{"image": "scene00.png", "fo')  # the merge, cut short
    done = tmp_path / ".results.jsonl.ngp-done.5678abcd"  # a finished run's folder, killed while being deleted
    done.mkdir()
    (done / "1-0.rows").write_text("0\t{}\n")
    calibrated = _spy(monkeypatch)
    counts = predict_folder(folder, out, resume=True)
    assert counts == {"images": 9, "errors": 1, "interrupted": False, "rank": 0} and calibrated == []
    assert _rows(out) == expected and _hidden(tmp_path) == []


def test_rows_written_where_process_0_does_not_see_them_leave_out_as_it_was(scenes, tmp_path, monkeypatch):
    from ngp_kornia.errors import OutputError
    from ngp_kornia.predict import JsonlWriter

    folder, expected = scenes
    out = tmp_path / "results.jsonl"
    out.write_text('{"image": "earlier.png", "error": "an earlier run"}\n')
    written = JsonlWriter.write_on_batch_end

    def elsewhere(self, trainer, module, prediction, *rest):  # scene03's row goes to another machine's disk
        if prediction[0][1]["image"] != "scene03.png":
            written(self, trainer, module, prediction, *rest)

    monkeypatch.setattr(JsonlWriter, "write_on_batch_end", elsewhere)
    with pytest.raises(OutputError, match=f"only 8 of 9 images have a row in .*; {out} is unchanged, and --resume"):
        predict_folder(folder, out)
    assert out.read_text() == '{"image": "earlier.png", "error": "an earlier run"}\n' and _hidden(tmp_path) == [RUN]
    monkeypatch.undo()
    calibrated = _spy(monkeypatch)
    assert predict_folder(folder, out, resume=True)["images"] == 9 and calibrated == ["scene03.png"]
    assert _rows(out) == expected and _hidden(tmp_path) == []


def test_without_resume_a_run_starts_over(scenes, tmp_path):
    folder, expected = scenes
    out = tmp_path / "results.jsonl"
    _leave_a_killed_run(folder, out, expected, done=[0, 1])
    (tmp_path / RUN / "0badc0de-0.rows").write_text('0\t{"image": "scene00.png", "focal": -1}\n')  # not kept
    predict_folder(folder, out)
    assert _rows(out) == expected and _hidden(tmp_path) == []


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"seed": 1}, "had other options"),
        ({"weights": "none"}, "had other options"),
        ({"images": "one fewer"}, "calibrates other images (9 then, 8 now"),
    ],
)
def test_a_resume_of_other_images_or_options_is_refused(scenes, tmp_path, capsys, change, message):
    folder, expected = scenes
    mine = tmp_path / "photos"
    mine.mkdir()
    for path in folder.iterdir():
        (mine / path.name).write_bytes(path.read_bytes())
    out = tmp_path / "results.jsonl"
    _leave_a_killed_run(mine, out, expected, done=[0])
    before = {p.name: p.read_bytes() for p in (tmp_path / RUN).iterdir()}
    if "images" in change:
        (mine / "scene07.png").unlink()
    options = [f"--{key}={value}" for key, value in change.items() if key != "images"]
    assert main(["predict", str(mine), "--out", str(out), "--resume", *options]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ngp: error: --resume: ") and message in err, err
    assert "run without --resume to start over" in err
    assert {p.name: p.read_bytes() for p in (tmp_path / RUN).iterdir()} == before and not out.exists()


def test_resume_without_an_unfinished_run_calibrates_every_image(scenes, tmp_path, capsys):
    folder, expected = scenes
    out = tmp_path / "results.jsonl"
    assert main(["predict", str(folder), "--out", str(out), "--resume"]) == 1
    err = capsys.readouterr().err
    assert err.splitlines()[0] == f"ngp: resuming {out}: no unfinished run to continue; calibrating 9"
    assert _rows(out) == expected


def test_rows_files_are_read_up_to_their_last_whole_row(tmp_path):
    path = tmp_path / "a.rows"
    good = '0\t{"image": "a.png"}\n2\t{"image": "c.png"}\n'
    for tail in ['3\t{"image": "d.p', "\0\0\0\0\n", '1\t{"image": "b.png"}\n', 'x\t{"image": "d.png"}\n',
                 '3\t["image"]\n', '3\t{"name": "d.png"}\n', '3 {"image": "d.png"}\n', '9\t{"image": "j.png"}\n']:
        path.write_text(good + tail + '4\t{"image": "e.png"}\n')
        assert [index for index, _ in read_rows(path, count=5)] == [0, 2], tail


def _start(folder, out, *options):
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out), *options]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


@pytest.mark.slow
def test_a_run_killed_halfway_and_resumed_has_every_row_once_as_if_never_stopped(tmp_path):
    folder = _write_scenes(tmp_path / "photos", range(40), size=(320, 240))
    out = tmp_path / "results.jsonl"
    proc = _start(folder, out)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:  # halfway: 20 of the 40 rows on the disk
        if sum(p.read_bytes().count(b"\n") for p in _rows_files(tmp_path)) >= 20:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert not out.exists() and _hidden(tmp_path) == [RUN]
    resumed = subprocess.run(
        [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out), "--resume",
         "--devices", "2"],  # the rest shared by two processes
        capture_output=True, text=True, timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    first = resumed.stderr.splitlines()[0]
    assert first.startswith(f"ngp: resuming {out}: ") and "40 rows written" in resumed.stdout, first
    assert int(first.split(": ")[2].split(" of ")[0]) >= 20  # the rows of the killed run were kept
    predict_folder(folder, tmp_path / "never_stopped.jsonl")
    assert _rows(out) == _rows(tmp_path / "never_stopped.jsonl")  # every image once, in order, the same rows
    assert _hidden(tmp_path) == []
