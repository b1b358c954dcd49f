"""The commands answer --help, --version and wrong arguments before they import torch, OpenCV or Lightning: each
case runs the entry point in a fresh interpreter and checks the answer and the modules it had imported."""

import json

import cv2
import numpy as np
import pytest

import ngp_kornia
from ngp_kornia.data.folder import IMAGE_EXTENSIONS, ImageFolder
from ngp_kornia.preflight import IMAGE_EXTENSIONS as LIGHT_EXTENSIONS
from ngp_kornia.preflight import check_folder, image_files
from tests.core_only import run_command


@pytest.fixture(scope="module")
def place(tmp_path_factory):
    root = tmp_path_factory.mktemp("start")
    (root / "empty").mkdir()
    (root / "notes").mkdir()
    (root / "notes" / "readme.txt").write_text("not an image")
    cv2.imwrite(str(root / "photo.png"), np.zeros((48, 64, 3), np.uint8))
    (root / "run.ckpt").write_bytes(b"a checkpoint")
    (root / "weights.pt").write_bytes(b"weights a user keeps")
    (root / "folder.pt").mkdir()
    return root


ANSWERS = [  # (entry, arguments, exit status, the start of the first stdout line or the last stderr line)
    ("ngp", ["--version"], 0, f"ngp {ngp_kornia.__version__}"),
    ("ngp", ["--help"], 0, "usage: ngp "),
    *[("ngp", [cmd, "--help"], 0, f"usage: ngp {cmd} ") for cmd in ("calibrate", "predict", "rectify", "demo")],
    ("ngp", ["render", "--help"], 0, "usage: ngp render "),
    ("ngp-train", ["--help"], 0, "usage: ngp-train "),
    ("ngp-train", ["--version"], 0, f"ngp-train {ngp_kornia.__version__}"),
    ("ngp-train", ["export", "--help"], 0, "usage: ngp-train export "),
    ("ngp", ["calibrate", "missing.jpg"], 1, "ngp: error: missing.jpg: file not found"),
    ("ngp", ["rectify", "missing.jpg", "-o", "out.png"], 1, "ngp: error: missing.jpg: file not found"),
    ("ngp", ["calibrate", "photo.png", "--bogus"], 2, "ngp calibrate: error: unrecognized option --bogus: see ngp"),
    ("ngp", ["calibrate", "photo.png", "--focla", "3"], 2, "ngp calibrate: error: unrecognized option --focla: did "),
    ("ngp", ["rectify", "photo.png", "-o", "x.png", "--mode", "sideways"], 2, "ngp rectify: error: argument --mode"),
    ("ngp", ["predict", "empty", "--out", "r.jsonl"], 1, "ngp: error: empty: no images found (looked for .jpg"),
    ("ngp", ["predict", "notes", "--out", "r.jsonl"], 1, "ngp: error: notes: no images found"),
    ("ngp", ["predict", "nowhere", "--out", "r.jsonl"], 1, "ngp: error: nowhere: no such folder"),
    ("ngp", ["predict", "photo.png", "--out", "r.jsonl"], 1, "ngp: error: photo.png: is a file, not a folder"),
    ("ngp", ["predict", ".", "--out", "r.jsonl", "--devices", "0"], 2, "ngp: error: --devices must be at least 1"),
    ("ngp", ["render", "out", "--size", "big"], 2, "ngp render: error: argument --size: must look like 640x480"),
    ("ngp-train", ["bogus"], 2, "ngp-train: error: argument COMMAND: invalid choice: 'bogus'"),
    ("ngp-train", ["fit", "--config", "zsnett"], 2, "ngp-train: error: --config zsnett: no such file"),
    ("ngp-train", ["export", "missing.ckpt", "x.pt"], 1, "ngp-train: error: checkpoint not found: missing.ckpt"),
    ("ngp-train", ["export", "run.ckpt", "run.ckpt", "--force"], 1, "ngp-train: error: run.ckpt is the checkpoint"),
    ("ngp-train", ["export", "run.ckpt", "weights.pt"], 1, "ngp-train: error: weights.pt exists; add --force"),
    ("ngp-train", ["export", "run.ckpt", "folder.pt"], 1, "ngp-train: error: folder.pt is a folder"),
]


@pytest.mark.parametrize(("entry", "args", "code", "answer"), ANSWERS, ids=[" ".join([e, *a]) for e, a, *_ in ANSWERS])
def test_answered_before_torch_is_imported(place, entry, args, code, answer):
    run = run_command(entry.replace("-", "_"), args, place)
    assert run.returncode == code, run.stderr[-2000:]
    said = run.stdout.splitlines()[0] if code == 0 else run.stderr.strip().splitlines()[-1]
    assert said.startswith(answer), (said, run.stderr[-2000:])
    assert "Traceback" not in run.stderr and run.heavy == []
    if code:  # errors are one line (a usage error: argparse's usage, then that line)
        assert len([line for line in run.stderr.splitlines() if "error" in line]) == 1
    assert (place / "weights.pt").read_bytes() == b"weights a user keeps" and not (place / "out").exists()


def test_a_command_that_runs_imports_torch_after_parsing(place):
    # the check above can fail: a run that gets past its arguments does import the heavy modules
    run = run_command("ngp", ["calibrate", "photo.png", "--weights", "none"], place)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout)["image"] == "photo.png" and {"torch", "cv2"} <= set(run.heavy)


def test_light_folder_check_lists_what_image_folder_lists(tmp_path):
    # the check that runs before torch is imported decides as ImageFolder does
    assert LIGHT_EXTENSIONS == IMAGE_EXTENSIONS
    (tmp_path / "sub" / ".hidden").mkdir(parents=True)
    (tmp_path / ".dot.jpg").write_bytes(b"x")
    (tmp_path / "UPPER.JPG").write_bytes(b"x")
    (tmp_path / "notes.txt").write_bytes(b"x")
    (tmp_path / "dir.png").mkdir()
    (tmp_path / "sub" / "a.webp").write_bytes(b"x")
    (tmp_path / "sub" / ".hidden" / "b.png").write_bytes(b"x")
    (tmp_path / "broken.tif").symlink_to(tmp_path / "nowhere.tif")
    for recursive in (False, True):
        listed = sorted(image_files(tmp_path, recursive))
        assert listed == ImageFolder(tmp_path, recursive=recursive).paths
    # a link to nothing is listed: its row then says the file is gone
    assert [p.name for p in sorted(image_files(tmp_path, True))] == ["UPPER.JPG", "broken.tif", "a.webp"]
    (tmp_path / "UPPER.JPG").unlink()
    (tmp_path / "broken.tif").unlink()
    with pytest.raises(ValueError, match="no images found .* use --recursive"):
        check_folder(tmp_path)
    check_folder(tmp_path, recursive=True)
