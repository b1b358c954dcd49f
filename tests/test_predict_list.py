"""ngp predict --list FILE: the images of a list file (one path per line, or a CSV file with a path column), paths
relative to the list's folder or absolute (on other disks), one row per listed image in list order, the same rows as
the folders give; and the list file's mistakes, each one line."""

import json
import shutil

import cv2
import pytest

from ngp_kornia.cli import main
from ngp_kornia.data.image_list import read_image_list
from ngp_kornia.errors import ManifestError
from ngp_kornia.predict import predict_folder, predict_list
from ngp_kornia.training.synth.render import render_scene


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def _scene(path, seed):
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(render_scene(seed, size=(160, 120)).image, cv2.COLOR_RGB2BGR))


def test_a_list_reads_text_and_csv_with_paths_relative_to_its_folder(tmp_path):
    listed = tmp_path / "lists" / "photos.txt"
    listed.parent.mkdir()
    (listed.parent / "a.jpg").touch()
    listed.write_text("\ufeffa.jpg\n\n  street/b.png \r\n/elsewhere/c.jpg\n~/d.jpg\n")
    images = read_image_list(listed)
    assert images.names[:3] == ["a.jpg", "street/b.png", "/elsewhere/c.jpg"] and images.names[3].endswith("/d.jpg")
    assert [str(p) for p in images.paths][:3] == [str(listed.parent / "a.jpg"), str(listed.parent / "street/b.png"),
                                                  "/elsewhere/c.jpg"]
    assert not images.names[3].startswith("~")  # the home folder, as a shell gives it to ngp calibrate
    manifest = tmp_path / "labels.csv"
    manifest.write_text("focal_px,IMAGE,roll_deg\n500,x.png,1\n,,\n600,\"y, z.png\",2\n")
    (tmp_path / "y, z.png").touch()
    assert read_image_list(manifest).names == ["x.png", "y, z.png"]
    manifest.write_text('image,Path\nignored.png,"y, z.png"\n')
    assert read_image_list(manifest).names == ["y, z.png"]  # the path column first


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("twice.txt", "a.png\nb.png\na.png\n", "twice.txt, line 3: a.png is listed on line 1 already; list it once"),
        ("empty.txt", "\n  \n", "lists no image; give one image path per line"),
        ("labels.csv", "file,focal\na.png,500\n", "no 'path' or 'image' column"),
        ("latin.txt", b"caf\xe9.png\n", "not a UTF-8 text file"),
    ],
)
def test_a_bad_list_is_one_line_naming_the_fix(tmp_path, name, text, message):
    listed = tmp_path / name
    listed.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ManifestError, match=message):
        read_image_list(listed)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """Three scenes, the first on another 'disk', and a list of them with a missing file."""
    root = tmp_path_factory.mktemp("collection")
    disk = tmp_path_factory.mktemp("other_disk")
    _scene(disk / "far.png", 0)
    _scene(root / "near" / "one.png", 1)
    _scene(root / "near" / "two.png", 2)
    (root / "list.txt").write_text(f"near/two.png\n{disk / 'far.png'}\nnear/gone.png\nnear/one.png\n")
    return root, disk


def test_the_command_writes_a_row_per_listed_image_in_list_order(small, tmp_path, capsys):
    root, disk = small
    out = tmp_path / "rows.jsonl"
    assert main(["predict", "--list", str(root / "list.txt"), "--out", str(out)]) == 1  # 1: the missing file
    captured = capsys.readouterr()
    assert "4 rows written" in captured.out and "1 of 4 images could not be read" in captured.err
    rows = _rows(out)
    assert [r["image"] for r in rows] == ["near/two.png", str(disk / "far.png"), "near/gone.png", "near/one.png"]
    assert "error" in rows[2] and str(root / "near" / "gone.png") in rows[2]["error"]
    predict_folder(root / "near", tmp_path / "folder.jsonl")
    by_name = {r["image"]: r for r in _rows(tmp_path / "folder.jsonl")}
    assert rows[0] == {**by_name["two.png"], "image": "near/two.png"}
    assert rows[3] == {**by_name["one.png"], "image": "near/one.png"}


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["FOLDER", "--list", "LIST"], 2, "give a folder or --list FILE, not both"),
        ([], 2, "give a folder or --list FILE"),
        (["--list", "LIST", "--recursive"], 2, "--recursive is for a folder; a --list names its files"),
        (["--list", "missing.txt"], 1, "--list missing.txt: no such file"),
        (["--list", "NOTHING"], 1, "none of its 2 listed files exists (relative paths are taken from the list's"),
        (["--list", "TWICE"], 1, "line 2: near/one.png is listed on line 1 already"),
    ],
)
def test_list_mistakes_are_one_line(small, tmp_path, capsys, args, code, message):
    root, _ = small
    (tmp_path / "nothing.txt").write_text("a.png\nb.png\n")
    (tmp_path / "twice.txt").write_text("near/one.png\nnear/one.png\n")
    (tmp_path / "near").symlink_to(root / "near")
    names = {"FOLDER": str(root / "near"), "LIST": str(root / "list.txt"), "NOTHING": str(tmp_path / "nothing.txt"),
             "TWICE": str(tmp_path / "twice.txt"), "missing.txt": "missing.txt"}
    argv = ["predict", *(names.get(a, a) for a in args), "--out", str(tmp_path / "rows.jsonl")]
    assert main(argv) == code
    err = capsys.readouterr().err
    assert err.startswith("ngp: error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "rows.jsonl").exists()


@pytest.mark.slow
def test_a_list_of_hundreds_in_two_folders_gives_the_rows_of_the_folders(tmp_path):
    # two folders on two "disks" (temporary folders apart), 150 images each: 10 scenes, 15 copies of each
    disks = [tmp_path / "disk1" / "street", tmp_path / "disk2" / "rooms"]
    for number, folder in enumerate(disks):
        for seed in range(10):
            _scene(folder / f"s{seed}_00.png", 10 * number + seed)
            for copy in range(1, 15):
                shutil.copy(folder / f"s{seed}_00.png", folder / f"s{seed}_{copy:02d}.png")
    folder_rows = []
    for folder in disks:
        predict_folder(folder, folder.parent / "rows.jsonl")
        folder_rows.append(_rows(folder.parent / "rows.jsonl"))
    # the list beside the second folder: its images relative, the first folder's absolute; interleaved
    first = [(str(disks[0] / r["image"]), r) for r in folder_rows[0]]
    second = [(f"rooms/{r['image']}", r) for r in folder_rows[1]]
    listed = [pair for pairs in zip(first, second, strict=True) for pair in pairs]
    (tmp_path / "disk2" / "all.csv").write_text("path,note\n" + "".join(f"{p},x\n" for p, _ in listed))
    counts = predict_list(tmp_path / "disk2" / "all.csv", tmp_path / "list.jsonl")
    assert counts == {"images": 300, "errors": 0, "interrupted": False, "rank": 0}
    assert _rows(tmp_path / "list.jsonl") == [{**row, "image": path} for path, row in listed]
