"""The COLMAP hand-off (``ngp_kornia.colmap``, ``ngp predict --colmap``): what it writes reads back through pycolmap
(cameras, gravity priors agreeing with the calibration's pitch and roll), it never touches what it does not own, a
rerun updates rather than duplicates, and COLMAP's own feature extraction and matching run on what it wrote."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

pycolmap = pytest.importorskip("pycolmap")

from ngp_kornia import calibrate  # noqa: E402
from ngp_kornia.cli import main  # noqa: E402
from ngp_kornia.colmap import displayed_to_stored, read_predictions, write_colmap_database  # noqa: E402
from ngp_kornia.errors import InputError, OutputError  # noqa: E402
from ngp_kornia.io import apply_orientation  # noqa: E402
from ngp_kornia.preflight import check_database  # noqa: E402
from ngp_kornia.training.synth.render import render_scene  # noqa: E402
from tests.core_only import ROOT, SITECUSTOMIZE  # noqa: E402

SIZE = (320, 240)


def pitch_roll(gravity) -> tuple[float, float]:
    """Pitch and roll in degrees of a gravity direction in the camera frame, by the README's conventions: the up
    vector is -gravity, pitch = asin(up_z), roll = atan2(up_x, -up_y)."""
    up = -np.asarray(gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    return math.degrees(math.asin(up[2])), math.degrees(math.atan2(up[0], -up[1]))


def save(path: Path, rgb: np.ndarray, orientation: int = 1) -> Path:
    """An image file; with an orientation tag, its pixels stored so that the tag turns them back to ``rgb``."""
    stored = {1: rgb, 6: np.rot90(rgb, 1), 8: np.rot90(rgb, -1)}[orientation]
    assert np.array_equal(apply_orientation(stored, orientation), rgb)
    image = Image.fromarray(np.ascontiguousarray(stored))
    exif = image.getexif()
    if orientation != 1:
        exif[0x0112] = orientation
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path, exif=exif, **({"quality": 95} if path.suffix == ".jpg" else {}))
    return path


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> dict:
    """Three rendered photos as files, and their calibrations by name."""
    folder = tmp_path_factory.mktemp("photos")
    names = {"plaza.png": 2, "sub/room.png": 3, "street.png": 5}
    files = {name: save(folder / name, render_scene(seed, SIZE).image) for name, seed in names.items()}
    calibrations = {name: calibrate(str(path)) for name, path in files.items()}
    assert all(bool(c.valid) for c in calibrations.values())
    return {"folder": folder, "calibrations": calibrations}


def plain(thing) -> str:
    """A pycolmap object's fields as text, for comparing (its arrays hold NaN where a value is unset)."""
    return repr(thing.todict())


def read_back(path: Path) -> dict:
    """Everything pycolmap reads back, by image name: image, camera, pose priors of the image."""
    with pycolmap.Database.open(path) as db:
        cameras = {c.camera_id: c for c in db.read_all_cameras()}
        priors = db.read_all_pose_priors()
        out = {}
        for image in db.read_all_images():
            own = [p for p in priors if p.corr_data_id == image.data_id]
            out[image.name] = {"image": image, "camera": cameras[image.camera_id], "priors": own}
        out["counts"] = {"cameras": db.num_cameras(), "images": db.num_images(), "priors": db.num_pose_priors(),
                         "rigs": db.num_rigs(), "frames": db.num_frames()}
    return out


@pytest.mark.parametrize("orientation", range(1, 9))
def test_displayed_to_stored_finds_each_pixel_where_the_file_stores_it(orientation):
    stored = np.arange(5 * 7).reshape(5, 7)
    displayed = apply_orientation(stored, orientation)
    height, width = displayed.shape
    A = displayed_to_stored(orientation, height, width)
    ys, xs = np.mgrid[0:height, 0:width]
    x_s, y_s, _ = np.einsum("ij,jhw->ihw", A, np.stack([xs, ys, np.ones_like(xs)]))
    assert np.array_equal(stored[y_s.astype(int), x_s.astype(int)], displayed)


def test_cameras_and_gravity_read_back_as_written(photos, tmp_path):
    database = tmp_path / "new.db"
    report = write_colmap_database(database, photos["calibrations"])
    assert sorted(report.added) == sorted(photos["calibrations"]) and not report.skipped
    back = read_back(database)
    assert back["counts"] == {"cameras": 3, "images": 3, "priors": 3, "rigs": 3, "frames": 3}
    for name, cal in photos["calibrations"].items():
        camera, priors = back[name]["camera"], back[name]["priors"]
        expected = cal.to_colmap()
        assert camera.model_name == expected["model"] == "SIMPLE_PINHOLE"
        assert (camera.width, camera.height) == SIZE and camera.has_prior_focal_length
        np.testing.assert_allclose(camera.params, expected["params"], rtol=1e-6)
        assert len(priors) == 1 and priors[0].has_gravity() and not priors[0].has_position()
        pitch, roll = pitch_roll(priors[0].gravity)
        assert abs(pitch - float(cal.pitch)) < 0.01 and abs(roll - float(cal.roll)) < 0.01, (name, pitch, roll, cal)
        assert pycolmap.compute_rot90_from_gravity(priors[0].gravity) == 0  # an upright photo needs no turn


def test_a_radial_camera_for_a_calibration_with_k1(photos, tmp_path):
    cal = calibrate(str(photos["folder"] / "plaza.png"), priors={"k1": "estimate"})
    write_colmap_database(tmp_path / "radial.db", {"plaza.png": cal})
    camera = read_back(tmp_path / "radial.db")["plaza.png"]["camera"]
    assert camera.model_name == "RADIAL" and camera.has_prior_focal_length
    np.testing.assert_allclose(camera.params, cal.to_colmap()["params"], rtol=1e-6)


@pytest.mark.parametrize("orientation", [6, 8])
def test_convention_gravity_is_that_of_the_stored_pixels_as_colmap_reads_them(photos, tmp_path, orientation):
    rgb = render_scene(2, SIZE).image
    path = save(tmp_path / "images" / "turned.jpg", rgb, orientation)
    cal = calibrate(str(path))  # as displayed: the tag applied
    assert int(cal.exif_orientation) == orientation and tuple(cal.image_size.tolist()) == (SIZE[1], SIZE[0])
    theirs, ours = tmp_path / "colmap.db", tmp_path / "ours.db"
    pycolmap.Database.open(theirs).close()
    pycolmap.import_images(theirs, tmp_path / "images")  # COLMAP's reader: the stored size, a coarse gravity
    write_colmap_database(ours, {"turned.jpg": cal})
    colmap, back = read_back(theirs)["turned.jpg"], read_back(ours)["turned.jpg"]
    assert (back["camera"].width, back["camera"].height) == (colmap["camera"].width, colmap["camera"].height)
    assert (back["camera"].width, back["camera"].height) == (SIZE[1], SIZE[0])
    coarse, fine = colmap["priors"][0].gravity, back["priors"][0].gravity
    angle = math.degrees(math.acos(np.clip(coarse @ fine, -1, 1)))
    assert angle < 15.0, (coarse, fine)  # the camera's pitch and roll apart, the same direction
    assert pycolmap.compute_rot90_from_gravity(fine) == pycolmap.compute_rot90_from_gravity(coarse) != 0
    # the principal point turns with the pixels (centred in both), the focal length stays
    np.testing.assert_allclose(back["camera"].params, [float(cal.focal), SIZE[1] / 2, SIZE[0] / 2], rtol=1e-6)
    turn = displayed_to_stored(orientation, SIZE[1], SIZE[0])[:2, :2]  # the gravity turned back to display
    pitch, roll = pitch_roll([*(turn.T @ fine[:2]), fine[2]])
    assert abs(pitch - float(cal.pitch)) < 0.01 and abs(roll - float(cal.roll)) < 0.01


def colmap_database(tmp_path: Path, folder: Path, mode=None) -> Path:
    """A database COLMAP made for the folder: its images, cameras, keypoints, a match and a GPS prior."""
    database = tmp_path / "existing.db"
    options = {} if mode is None else {"camera_mode": mode}
    pycolmap.Database.open(database).close()
    pycolmap.import_images(database, folder, **options)
    with pycolmap.Database.open(database) as db:
        images = sorted(db.read_all_images(), key=lambda image: image.name)
        for image in images:
            db.write_keypoints(image.image_id, np.full((4, 2), float(image.image_id), dtype=np.float32))
        db.write_matches(images[0].image_id, images[-1].image_id, np.array([[0, 1], [2, 3]], dtype=np.uint32))
        prior = pycolmap.PosePrior(position=[1.0, 2.0, 3.0], coordinate_system=pycolmap.PosePriorCoordinateSystem.WGS84)
        prior.corr_data_id = images[0].data_id
        db.write_pose_prior(prior)
    return database


def snapshot(database: Path) -> dict:
    """What the database holds besides what ours may change: keypoints, matches, frames, rigs."""
    with pycolmap.Database.open(database) as db:
        images = db.read_all_images()
        return {
            "keypoints": {i.name: db.read_keypoints(i.image_id).tolist() for i in images},
            "matches": {pair: m.tolist() for pair, m in zip(*db.read_all_matches(), strict=True)},
            "frames": [plain(f) for f in db.read_all_frames()],
            "rigs": [plain(r) for r in db.read_all_rigs()],
        }


def test_an_existing_database_keeps_what_is_not_ours(photos, tmp_path):
    database = colmap_database(tmp_path, photos["folder"])
    before, kept = read_back(database), snapshot(database)
    ours = {name: photos["calibrations"][name] for name in ("street.png", "plaza.png")}
    new = calibrate(render_scene(7, SIZE).image)
    report = write_colmap_database(database, {**ours, "new.png": new})
    assert report.added == ["new.png"] and sorted(report.updated) == sorted(ours) and not report.camera_kept
    after = read_back(database)
    other = "sub/room.png"  # not ours: its image, camera and prior are as COLMAP left them
    assert plain(after[other]["image"]) == plain(before[other]["image"])
    assert plain(after[other]["camera"]) == plain(before[other]["camera"])
    assert [plain(p) for p in after[other]["priors"]] == [plain(p) for p in before[other]["priors"]]
    for name, cal in ours.items():  # ours: the same ids, our camera and gravity
        assert after[name]["image"].image_id == before[name]["image"].image_id
        assert after[name]["camera"].camera_id == before[name]["camera"].camera_id
        np.testing.assert_allclose(after[name]["camera"].params, cal.to_colmap()["params"], rtol=1e-6)
        assert after[name]["camera"].has_prior_focal_length and len(after[name]["priors"]) == 1
        assert abs(pitch_roll(after[name]["priors"][0].gravity)[0] - float(cal.pitch)) < 0.01
    gps = after["plaza.png"]["priors"][0]  # its GPS position stays beside the gravity
    assert gps.position.tolist() == [1.0, 2.0, 3.0] and gps.coordinate_system.name == "WGS84"
    now = snapshot(database)
    assert {name: now["keypoints"][name] for name in kept["keypoints"]} == kept["keypoints"]
    assert now["matches"] == kept["matches"]
    assert now["frames"][:3] == kept["frames"] and now["rigs"][:3] == kept["rigs"]
    # one prior each for ours (room.png's the GPS one it had), none for the other
    assert after["counts"] == {"cameras": 4, "images": 4, "priors": 3, "rigs": 4, "frames": 4}


def test_a_camera_shared_with_other_images_is_left_as_it_is(photos, tmp_path):
    database = colmap_database(tmp_path, photos["folder"], pycolmap.CameraMode.SINGLE)
    before = read_back(database)
    ours = {name: photos["calibrations"][name] for name in ("street.png", "plaza.png")}
    report = write_colmap_database(database, ours)
    assert sorted(report.camera_kept) == sorted(ours) and "sub/room.png" in report.camera_kept["street.png"]
    after = read_back(database)
    assert after["counts"]["cameras"] == 1
    assert plain(after["plaza.png"]["camera"]) == plain(before["plaza.png"]["camera"])
    assert abs(pitch_roll(after["plaza.png"]["priors"][0].gravity)[1] - float(ours["plaza.png"].roll)) < 0.01
    # every photo of the camera written, with one focal length: the camera is theirs, and updated
    paths = [str(photos["folder"] / name) for name in before if name != "counts"]
    shared = calibrate(paths, priors={"shared_intrinsics": True})
    names = sorted(name for name in before if name != "counts")
    report = write_colmap_database(database, dict(zip(names, shared, strict=True)))
    assert not report.camera_kept and sorted(report.updated) == names
    camera = read_back(database)["plaza.png"]["camera"]
    assert camera.has_prior_focal_length and camera.params[0] == pytest.approx(float(shared[0].focal), rel=1e-6)


def test_a_rerun_updates_rather_than_duplicates(photos, tmp_path):
    database = tmp_path / "rerun.db"
    write_colmap_database(database, photos["calibrations"])
    first = read_back(database)
    known = {name: calibrate(str(photos["folder"] / name), priors={"focal": 300.0}) for name in photos["calibrations"]}
    report = write_colmap_database(database, known)
    assert not report.added and sorted(report.updated) == sorted(known)
    second = read_back(database)
    assert second["counts"] == first["counts"]
    for name, cal in known.items():
        assert second[name]["image"].image_id == first[name]["image"].image_id
        assert second[name]["camera"].params[0] == pytest.approx(300.0)
        assert abs(pitch_roll(second[name]["priors"][0].gravity)[1] - float(cal.roll)) < 0.01


def test_an_image_of_another_size_is_left_alone(photos, tmp_path):
    folder = tmp_path / "other"
    save(folder / "plaza.png", render_scene(2, (160, 120)).image)
    database = colmap_database(tmp_path, folder)
    before = read_back(database)
    report = write_colmap_database(database, {"plaza.png": photos["calibrations"]["plaza.png"]})
    assert "160x120" in report.skipped["plaza.png"] and not report.updated
    after = read_back(database)
    assert plain(after["plaza.png"]["camera"]) == plain(before["plaza.png"]["camera"])
    assert after["counts"] == before["counts"]


def test_what_is_not_a_colmap_database_is_refused_and_kept(photos, tmp_path):
    import sqlite3

    png = photos["folder"] / "plaza.png"
    rows = tmp_path / "rows.jsonl"
    rows.write_text('{"image": "a.png", "error": "unreadable"}\n')
    foreign = tmp_path / "other.sqlite"
    with sqlite3.connect(foreign) as connection:
        connection.execute("CREATE TABLE notes (text)")
    for path in (png, rows, foreign):
        data = path.read_bytes()
        with pytest.raises(OutputError, match="not a COLMAP database"):
            write_colmap_database(path, photos["calibrations"])
        assert path.read_bytes() == data
    with pytest.raises(OutputError, match="is a folder"):
        check_database(tmp_path)
    (tmp_path / "empty.db").touch()  # an empty file is a new database
    assert write_colmap_database(tmp_path / "empty.db", photos["calibrations"]).added


def test_rows_without_a_valid_calibration_are_skipped_and_bad_input_refused(photos, tmp_path):
    rows = tmp_path / "rows.jsonl"
    good = {"image": "plaza.png", **photos["calibrations"]["plaza.png"].to_dict()}
    lines = [good, {"image": "bad.png", "error": "truncated file"}, {**good, "image": "flat.png", "valid": False}]
    rows.write_text("".join(json.dumps(row) + "\n" for row in lines))
    report = write_colmap_database(tmp_path / "rows.db", read_predictions(rows))
    assert report.added == ["plaza.png"]
    assert report.skipped == {"bad.png": "no calibration (truncated file)",
                              "flat.png": "no valid calibration (valid is false)"}
    batch = calibrate(torch.rand(2, 3, 32, 32))
    for name, value, match in [("/abs/a.png", good, "relative"), ("a\\b.png", good, "relative"),
                               ("a.png", {"focal": 1.0}, "lacks K"), ("a.png", 3.0, "float"),
                               ("a.png", batch, r"calibration\[0\]")]:
        with pytest.raises(InputError, match=match):
            write_colmap_database(tmp_path / "refused.db", {name: value})
    assert not (tmp_path / "refused.db").exists()
    rows.write_text("not json\n")
    with pytest.raises(InputError, match="rows.jsonl:1"):
        read_predictions(rows)



# --- ngp predict --colmap -------------------------------------------------------------------------------------


def test_predict_writes_the_database_and_a_rerun_updates_it(photos, tmp_path, capsys):
    folder = tmp_path / "photos"
    for name in ("plaza.png", "sub/room.png"):
        save(folder / name, np.asarray(Image.open(photos["folder"] / name)))
    (folder / "broken.png").write_bytes(b"not an image")
    database, rows = tmp_path / "colmap" / "database.db", tmp_path / "rows.jsonl"  # its folder made too
    args = ["predict", str(folder), "--recursive", "--out", str(rows), "--colmap", str(database)]
    assert main(args) == 1  # the broken file's error row: the others are written
    out, err = capsys.readouterr()
    assert f"COLMAP database {database}: 2 images added, 0 updated, 1 skipped" in out
    assert "ngp: colmap: broken.png: no calibration (" in err
    back = read_back(database)
    for name, row in read_predictions(rows).items():
        if "error" not in row:
            assert abs(pitch_roll(back[name]["priors"][0].gravity)[0] - row["pitch"]) < 0.01
            assert back[name]["camera"].params[0] == pytest.approx(row["focal"], rel=1e-6)
    assert main(args) == 1
    assert "2 images added" not in (out := capsys.readouterr()[0]) and "0 images added, 2 updated" in out
    assert read_back(database)["counts"] == back["counts"]


def test_predict_refuses_a_file_that_is_not_a_colmap_database_before_the_run(photos, tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    out = tmp_path / "rows.jsonl"
    assert main(["predict", str(photos["folder"]), "--out", str(out), "--colmap", str(notes)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ngp: error: ") and "is not a COLMAP database" in err and err.count("\n") == 1
    assert notes.read_text() == "my notes\n" and not out.exists()
    assert main(["predict", str(photos["folder"]), "--out", str(out), "--colmap", str(out)]) == 1
    assert "is also --out" in capsys.readouterr().err and not out.exists()


def test_predict_colmap_names_the_extra_where_pycolmap_is_missing(tmp_path):
    (tmp_path / "sitecustomize.py").write_text(SITECUSTOMIZE.format(hidden=("pycolmap",)))
    env = {"PYTHONPATH": f"{tmp_path}:{ROOT}", "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    save(tmp_path / "photos" / "a.png", np.zeros((8, 8, 3), np.uint8))
    command = [sys.executable, "-m", "ngp_kornia.cli", "predict", "photos", "-o", "r.jsonl", "--colmap", "db.db"]
    run = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert run.returncode == 1 and run.stdout == "" and run.stderr.count("\n") == 1, run.stderr[-2000:]
    assert run.stderr.strip().endswith("pip install 'ngp-kornia[colmap]'")
    assert not (tmp_path / "db.db").exists() and not (tmp_path / "r.jsonl").exists()


# --- COLMAP itself on what was written ------------------------------------------------------------------------


def rotating_camera(tmp_path: Path) -> Path:
    """Two photos of one rendered street from a camera turning about its centre (warped from a wider render), the
    second also stored turned with an orientation tag: views COLMAP can match, though not triangulate."""
    import cv2

    from ngp_kornia.geometry.camera import rotation_from_angles
    from ngp_kornia.training.synth.render_config import RenderConfig

    focal = 420.0
    fov = 2.0 * math.degrees(math.atan(480.0 / focal))  # 1280x960 at the focal length of the 640x480 views
    wide = render_scene(5, (1280, 960), RenderConfig(fov_v=(fov, fov), pitch=(5, 5), roll=(0, 0), yaw=(20, 20)))
    K = np.array([[focal, 0.0, 319.5], [0.0, focal, 239.5], [0.0, 0.0, 1.0]])
    folder = tmp_path / "images"
    for name, angles, orientation in (("a.png", (3, -4, -8), 1), ("b.png", (-2, 5, 6), 1), ("c.jpg", (-2, 5, 6), 6)):
        turn = rotation_from_angles(*(torch.tensor([float(a)]) for a in angles))[0].double().numpy()
        view = cv2.warpPerspective(wide.image, K @ turn @ np.linalg.inv(wide.K.numpy()), (640, 480),
                                   flags=cv2.INTER_AREA)
        save(folder / name, view, orientation)
    return folder


def test_colmap_extracts_and_matches_on_the_database_and_its_geometry_agrees_with_the_gravity(tmp_path):
    folder = rotating_camera(tmp_path)
    names = sorted(p.name for p in folder.iterdir())
    database = tmp_path / "database.db"
    write_colmap_database(database, {name: calibrate(str(folder / name)) for name in names})
    written = read_back(database)
    pycolmap.extract_features(database, folder, device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, verification_options=pycolmap.TwoViewGeometryOptions(
        compute_relative_pose=True), device=pycolmap.Device.cpu)
    back = read_back(database)
    assert back["counts"] == written["counts"]  # COLMAP took our images, cameras and priors, and added none
    gravity = {}
    for name in names:
        assert plain(back[name]["camera"]) == plain(written[name]["camera"])
        assert [plain(p) for p in back[name]["priors"]] == [plain(p) for p in written[name]["priors"]]
        gravity[name] = back[name]["priors"][0].gravity
    assert [pycolmap.compute_rot90_from_gravity(gravity[n]) for n in names] == [0, 0, 3]  # c.jpg: stored turned
    with pycolmap.Database.open(database) as db:
        for first, second in (("a.png", "b.png"), ("a.png", "c.jpg"), ("b.png", "c.jpg")):
            assert db.num_keypoints_for_image(back[first]["image"].image_id) > 100
            geometry = db.read_two_view_geometry(back[first]["image"].image_id, back[second]["image"].image_id)
            assert len(geometry.inlier_matches) > 100, (first, second)
            # the first camera's gravity turned into the second camera's frame by COLMAP's relative rotation
            turned = geometry.cam2_from_cam1.rotation.matrix() @ gravity[first]
            angle = math.degrees(math.acos(np.clip(turned @ gravity[second], -1.0, 1.0)))
            assert angle < 2.0, (first, second, angle)
