"""The camera options on the command line: --gravity, --principal-point, --k1, --same-camera (ngp calibrate and
ngp predict) and --truth for the overlays."""

import json

import cv2
import numpy as np
import pytest

from ngp_kornia.cli import main
from ngp_kornia.predict import predict_folder
from ngp_kornia.training.synth.render import RenderConfig, render_dataset

CAMERA = {"fov_v": (55.0, 55.0), "kinds": {"street": 1.0}}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Three renders of one camera, with their ground_truth.json."""
    root = tmp_path_factory.mktemp("camera")
    render_dataset(root, 3, seed=4, size=(320, 240), config=RenderConfig(**CAMERA))
    return root


def _rows(capsys):
    return [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]


def test_same_camera_gives_every_photo_one_focal_length(folder, capsys):
    images = sorted(str(p) for p in folder.glob("*.png"))
    assert main(["calibrate", *images, "--weights", "none"]) == 0
    alone = {row["focal"] for row in _rows(capsys)}
    assert main(["calibrate", *images, "--weights", "none", "--same-camera"]) == 0
    rows = _rows(capsys)
    focals = [row["focal"] for row in rows]
    # one number, rounded alike but for float32's last digits in each photo's K
    assert len(alone) == 3 and max(focals) - min(focals) < 1e-4 * focals[0]
    assert all(row["shared"] == ["focal"] and row["shared_photos"] == 3 for row in rows)


def test_predict_same_camera_shares_per_folder(folder, tmp_path):
    out = tmp_path / "rows.jsonl"
    assert predict_folder(folder, out, weights="none", same_camera=True)["images"] == 3
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    focals = [row["focal"] for row in rows]
    assert max(focals) - min(focals) < 1e-4 * focals[0] and {row["shared_photos"] for row in rows} == {3}
    with pytest.raises(ValueError, match="exif"):
        predict_folder(folder, out, weights="none", same_camera=True, exif=True)


def test_predict_same_camera_keeps_every_row_beside_a_photo_without_lines(folder, tmp_path, capsys):
    # a line-free photo in the folder once ended the run with no rows at all (exit 1)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for image in sorted(folder.glob("*.png"))[:2]:
        (mixed / image.name).write_bytes(image.read_bytes())
    cv2.imwrite(str(mixed / "blank.png"), np.full((240, 320, 3), 128, np.uint8))
    out = tmp_path / "rows.jsonl"
    assert main(["predict", str(mixed), "-o", str(out), "--weights", "none", "--same-camera"]) == 0
    rows = {row["image"]: row for row in map(json.loads, out.read_text().splitlines())}
    assert len(rows) == 3 and not rows["blank.png"]["valid"] and rows["blank.png"]["confidence"] == 0
    assert all(rows[name]["valid"] and rows[name]["shared_photos"] == 2 for name in rows if name != "blank.png")
    assert "warning" not in capsys.readouterr().err


def test_predict_same_camera_says_when_a_folder_shares_nothing(folder, tmp_path, capsys):
    tree = tmp_path / "tree"
    for image in sorted(folder.glob("*.png"))[:2]:  # one photo per folder: nothing to share
        (tree / image.stem).mkdir(parents=True)
        (tree / image.stem / image.name).write_bytes(image.read_bytes())
    out = tmp_path / "tree.jsonl"
    assert main(["predict", str(tree), "-o", str(out), "--weights", "none", "--same-camera", "--recursive"]) == 0
    err = capsys.readouterr().err
    assert err.count("ngp: warning:") == 1 and "2 of the 2 folders have fewer than two photos" in err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 2 and all("shared_photos" not in row and row["fov_v_std"] > 0 for row in rows)


def test_images_may_follow_the_principal_point(folder, capsys):
    images = [str(p) for p in sorted(folder.glob("*.png"))[:2]]
    assert main(["calibrate", "--weights", "none", "--principal-point", "161", "118", *images]) == 0
    rows = _rows(capsys)
    assert [r["image"] for r in rows] == images and all((r["cx"], r["cy"]) == (161.0, 118.0) for r in rows)
    assert main(["calibrate", "--weights", "none", "--principal-point", "estimate", images[0]]) == 0
    assert [r["image"] for r in _rows(capsys)] == images[:1]


def test_camera_options_reach_calibrate(folder, capsys):
    image = str(sorted(folder.glob("*.png"))[0])
    assert main(["calibrate", image, "--weights", "none", "--gravity", "3", "-2", "--gravity-std", "2",
                 "--principal-point", "161", "118", "--k1", "-0.05"]) == 0
    row = _rows(capsys)[0]
    assert row["gravity"] == {"pitch": 3.0, "roll": -2.0, "std": 2.0}
    assert (row["cx"], row["cy"]) == pytest.approx((161.0, 118.0), abs=1e-3) and row["k1"] == pytest.approx(-0.05)
    assert main(["calibrate", image, "--weights", "none", "--principal-point", "estimate", "--k1", "estimate"]) == 0
    row = _rows(capsys)[0]
    assert "principal_point_std" in row and "k1" in row


@pytest.mark.parametrize(("options", "message"), [
    (["--principal-point", "1"], "--principal-point"),
    (["--k1", "strong"], "--k1"),
    (["--gravity-std", "1"], "without gravity"),
])
def test_bad_camera_options_are_one_line_errors(folder, capsys, options, message):
    image = str(sorted(folder.glob("*.png"))[0])
    assert main(["calibrate", image, "--weights", "none", *options]) != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_overlay_draws_the_true_horizon_of_a_truth_file(folder, tmp_path, capsys):
    image = sorted(folder.glob("*.png"))[0]
    plain, true = tmp_path / "plain.png", tmp_path / "true.png"
    assert main(["calibrate", str(image), "--weights", "none", "--overlay", str(plain)]) == 0
    assert main(["calibrate", str(image), "--weights", "none", "--overlay", str(true), "--truth", str(folder)]) == 0
    a, b = cv2.imread(str(plain)), cv2.imread(str(true))
    magenta = np.array([255, 80, 255])[::-1]  # BGR on disk
    assert (np.abs(b.astype(int) - magenta).sum(-1) < 40).sum() > 50
    assert (np.abs(a.astype(int) - magenta).sum(-1) < 40).sum() == 0
    assert main(["calibrate", str(image), "--weights", "none", "--overlay", str(true), "--force",
                 "--truth", str(tmp_path / "missing.csv")]) != 0
    assert "missing.csv" in capsys.readouterr().err


def test_rectify_undistorts_a_bent_photo(tmp_path, capsys):
    from ngp_kornia.training.synth.render import render_scene

    bent = render_scene(5, (640, 480), RenderConfig(kinds={"street": 1.0}, k1_range=(-0.25, -0.25)))
    path = tmp_path / "bent.png"
    cv2.imwrite(str(path), cv2.cvtColor(bent.image, cv2.COLOR_RGB2BGR))
    plain, straight = tmp_path / "plain.png", tmp_path / "straight.png"
    common = ["--weights", "none", "--mode", "level", "--crop", "valid"]
    assert main(["rectify", str(path), *common, "-o", str(plain)]) == 0
    assert main(["rectify", str(path), *common, "--k1", "estimate", "-o", str(straight)]) == 0
    # the undistorted view is another image (barrel distortion undone: the valid centre is smaller than the input)
    a, b = cv2.imread(str(plain)), cv2.imread(str(straight))
    assert b.shape[0] < a.shape[0] or np.abs(cv2.resize(b, a.shape[1::-1]).astype(int) - a).mean() > 5
