"""ngp predict stopped early: Ctrl+C and SIGTERM keep the finished rows as valid JSON Lines, in one process and in
several, and the run folder for --resume; an error (a file-size limit, a full disk) keeps them the same way and
leaves no temporary file; the run folder of a killed run is deleted by the next run that does not resume, and a run
still going is never touched; the caller's signal handlers are back after a run."""

import errno
import fcntl
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import cv2
import pytest

from ngp_kornia.cli import main
from ngp_kornia.errors import OutputError
from ngp_kornia.predict import JsonlWriter, predict_folder
from ngp_kornia.training.synth.render import render_scene

#: an earlier run's results in the file a run replaces
OLD_RESULTS = '{"image": "earlier.png", "error": "an earlier run"}\n'


def _photos(folder, count):
    """``count`` copies of one small scene: cheap to write, each a second or so to calibrate."""
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "scene000.png"), cv2.cvtColor(render_scene(0, (160, 120)).image, cv2.COLOR_RGB2BGR))
    for i in range(1, count):
        (folder / f"scene{i:03d}.png").write_bytes((folder / "scene000.png").read_bytes())
    return folder


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _visible(folder):
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def _run_files(tmp_path):
    """The files of the run folder of results.jsonl: its rows files and run.json (no temporary file)."""
    return sorted(p.name.split("-")[-1] if p.suffix == ".rows" else p.name for p in (tmp_path / RUN).iterdir())


#: the run folder of results.jsonl
RUN = ".results.jsonl.ngp-run"


def _start(tmp_path, devices, count=200):
    """``ngp predict`` on ``count`` images in its own session, once at least two rows per process are written."""
    folder, out = _photos(tmp_path / "photos", count), tmp_path / "results.jsonl"
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", str(folder), "--out", str(out)]
    pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, "start_new_session": True}
    proc = subprocess.Popen([*command, "--devices", str(devices)], **pipes)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        written = list((tmp_path / RUN).glob("*.rows")) if (tmp_path / RUN).is_dir() else []
        if sum(p.read_bytes().count(b"\n") for p in written if p.is_file()) >= 2 * devices:
            break
        time.sleep(0.2)
    assert proc.poll() is None, "the run ended before it could be stopped"
    return proc, out


# (signal, sent to): Ctrl+C reaches the terminal's whole process group; `kill PID`, or a service manager that stops
# the main process, sends SIGTERM to it alone; a service manager that stops the whole group sends it to every one
STOPS = [
    pytest.param(signal.SIGINT, "group", 1, id="ctrl-c"),
    pytest.param(signal.SIGINT, "group", 2, id="ctrl-c-2-processes"),
    pytest.param(signal.SIGTERM, "process", 1, id="sigterm"),
    pytest.param(signal.SIGTERM, "process", 2, id="sigterm-2-processes"),
    pytest.param(signal.SIGTERM, "group", 2, id="sigterm-to-the-group-2-processes", marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("signum", "to", "devices"), STOPS)
def test_a_stopped_run_keeps_the_finished_rows(tmp_path, signum, to, devices):
    proc, out = _start(tmp_path, devices)
    os.killpg(proc.pid, signum) if to == "group" else os.kill(proc.pid, signum)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, (stderr[-2000:], stdout[-2000:])
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("ngp: interrupted: the "), (stderr[-2000:], stdout[-2000:])
    rows = _rows(out)  # every line is whole JSON
    assert 2 <= len(rows) < 200 and f"the {len(rows)} images finished are in {out}" in lines[0]
    assert lines[0].endswith("run the same command with --resume to calibrate the rest")
    names = [r["image"] for r in rows]
    assert names == sorted(set(names)) and all("focal" in r for r in rows)  # folder order, each once, complete
    # the run folder stays for --resume, without a temporary file
    assert _visible(tmp_path) == ["photos", "results.jsonl"] and _hidden(tmp_path) == [RUN]
    assert _run_files(tmp_path) == [f"{rank}.rows" for rank in range(devices)] + ["run.json"]


_LIMITED = textwrap.dedent(
    """
    import resource, sys
    from ngp_kornia.errors import OutputError
    from ngp_kornia.predict import predict_folder
    limit = int(sys.argv[3])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # writing past it fails with EFBIG
    try:
        predict_folder(sys.argv[1], sys.argv[2], devices=int(sys.argv[4]))
    except OutputError as err:
        print(err)
    """
)


@pytest.mark.parametrize("devices", [1, 2])
def test_a_file_size_limit_keeps_the_rows_and_leaves_no_temporary_file(tmp_path, devices):
    folder, out = _photos(tmp_path / "photos", 6 if devices == 1 else 24), tmp_path / "results.jsonl"
    out.write_text(OLD_RESULTS)
    row = len(json.dumps({"image": "scene000.png", **_one_row(folder, tmp_path)})) + 1
    # a forked process that stops writes its traceback to a file under the same limit (torch reads it back): room
    # for it beside the rows, and images enough to reach the limit all the same
    limit = int(2.5 * row) + (4096 if devices > 1 else 0)
    command = [sys.executable, "-c", _LIMITED, str(folder), str(out), str(limit), str(devices)]
    run = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    message = run.stdout.strip()
    assert message.startswith("the run stopped: ") and "File too large" in message, (message, run.stderr[-2000:])
    if devices == 1:  # the rows written before the limit, cut to whole rows, are the results
        rows = _rows(out)
        assert message.endswith(f"the {len(rows)} rows finished are in {out}") and len(rows) == 2
        assert [r["image"] for r in rows] == ["scene000.png", "scene001.png"] and all("focal" in r for r in rows)
    elif message.endswith(f"{out} is unchanged"):  # the merged rows do not fit either: the old results stay
        assert out.read_text() == OLD_RESULTS
    else:  # on a busy machine one process may have finished two rows while the other had none: those fit
        rows = _rows(out)
        assert message.endswith(f"the {len(rows)} rows finished are in {out}") and 0 < len(rows) <= limit // row
        assert all("focal" in r for r in rows)
    assert _hidden(tmp_path) == [RUN] and _visible(tmp_path) == ["photos", "results.jsonl"]
    assert _run_files(tmp_path) == [f"{rank}.rows" for rank in range(devices)] + ["run.json"]


def _one_row(folder, tmp_path):
    """The row of scene000.png, less its name (a row's length does not depend on the copy)."""
    single = tmp_path / "single"
    single.mkdir()
    (single / "scene000.png").write_bytes((folder / "scene000.png").read_bytes())
    predict_folder(single, tmp_path / "single.jsonl")
    (row,) = _rows(tmp_path / "single.jsonl")
    for path in (single / "scene000.png", tmp_path / "single.jsonl"):
        path.unlink()
    single.rmdir()
    return {k: v for k, v in row.items() if k != "image"}


def test_a_full_disk_keeps_whole_rows_and_the_handlers_as_they_were(tmp_path, monkeypatch):
    folder, out = _photos(tmp_path / "photos", 4), tmp_path / "results.jsonl"
    written = JsonlWriter.write_on_batch_end

    def full_after_two(self, *args, **kwargs):
        if self.images == 2:
            self.rows.file.write(b'2\t{"image": "scene002.png", "fo')  # part of a row reaches the file: disk full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return written(self, *args, **kwargs)

    monkeypatch.setattr(JsonlWriter, "write_on_batch_end", full_after_two)
    handlers = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]
    with pytest.raises(OutputError, match=r"the run stopped: \[Errno 28\] No space left on device; the 2 rows"):
        predict_folder(folder, out)
    assert [r["image"] for r in _rows(out)] == ["scene000.png", "scene001.png"]
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == handlers
    (rows_file,) = (tmp_path / RUN).glob("*.rows")  # cut back to its whole rows: --resume takes them
    text = rows_file.read_text()
    assert _hidden(tmp_path) == [RUN] and text.count("\n") == 2 and text.endswith("}\n")


def test_the_next_run_deletes_what_a_killed_run_left(tmp_path):
    proc, out = _start(tmp_path, 1)
    os.killpg(proc.pid, signal.SIGKILL)  # no chance to clean up
    proc.communicate(timeout=60)
    assert _hidden(tmp_path) == [RUN] and _run_files(tmp_path) == ["0.rows", "run.json"]
    unrelated = tmp_path / ".results.jsonl.notes"
    unrelated.write_text("someone else's file\n")
    folder = tmp_path / "photos"
    for path in sorted(folder.iterdir())[3:]:
        path.unlink()
    predict_folder(folder, out)  # without resume: starts over
    assert len(_rows(out)) == 3
    assert _hidden(tmp_path) == [".results.jsonl.notes"] and unrelated.read_text() == "someone else's file\n"


def test_a_run_still_going_is_never_touched(tmp_path, capsys):
    folder, out = _photos(tmp_path / "photos", 2), tmp_path / "results.jsonl"
    live = tmp_path / RUN / "0123abcd-1.rows"  # a file another run still writes: locked
    live.parent.mkdir()
    live.write_text('0\t{"image": "scene000.png"}\n')
    with live.open("rb") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)
        for resume in ([], ["--resume"]):
            assert main(["predict", str(folder), "--out", str(out), *resume]) == 1
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "another ngp predict is writing" in err and "give another --out" in err
    assert live.read_text() == '0\t{"image": "scene000.png"}\n' and not out.exists()


def test_the_callers_signal_handlers_are_back_after_a_run(tmp_path, capsys):
    folder = _photos(tmp_path / "photos", 1)

    def mine(signum, frame):
        raise AssertionError("not called")

    before = [signal.signal(s, mine) for s in (signal.SIGINT, signal.SIGTERM)]
    try:
        predict_folder(folder, tmp_path / "a.jsonl")
        assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == [mine, mine]
        assert main(["predict", str(folder), "--out", str(tmp_path / "b.jsonl")]) == 0
        assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == [mine, mine]
    finally:
        for number, handler in zip((signal.SIGINT, signal.SIGTERM), before, strict=True):
            signal.signal(number, handler)
