import math
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io
import torch

from ngp_kornia.data import YorkUrbanDB, load_labelled_segments, published_horizon, rotation_from_yud_vps
from ngp_kornia.geometry.camera import rotation_from_angles
from ngp_kornia.metrics import horizon_error

SHARED_YUD = Path(os.environ.get("YUD_ROOT", "/work/shared/data/YorkUrbanDB"))

FOCAL_MM, PIXEL_MM, PP = 5.0, 0.01, (80.25, 60.5)  # f = 500 px
W, H = 160, 120
# name -> (pitch, roll, yaw) in degrees; "IMG_D" is listed but absent from the folder
CAMERAS = {"IMG_A": (10.0, 0.0, 20.0), "IMG_B": (-5.0, 8.0, -30.0), "IMG_C": (0.0, -3.0, 0.0)}
NAMES = ["IMG_A", "IMG_B", "IMG_C", "IMG_D"]
TRAIN, TEST = [3, 1], [2, 4]  # 1-based into NAMES
RAW_UP_YUP = np.array([0.0, 1.0, 0.1]) / np.linalg.norm([0.0, 1.0, 0.1])  # camera frame y up: pitch ~5.7 deg


def _yud_vp_from_rotation(R: torch.Tensor) -> np.ndarray:
    """Inverse of the reader's conversion, with arbitrary column signs as in the real files."""
    cols = torch.stack([R[:, 0], -R[:, 1], -R[:, 2]], -1)  # vertical stored as "up", third axis flipped
    return (torch.diag(torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)) @ cols).numpy()


def _names_cell(names):
    cell = np.empty((len(names), 1), dtype=object)
    for i, n in enumerate(names):
        cell[i, 0] = n + "\\"
    return cell


@pytest.fixture()
def fake_yud(tmp_path: Path) -> Path:
    root = tmp_path / "YorkUrbanDB"
    root.mkdir()
    scipy.io.savemat(
        root / "cameraParameters.mat",
        {"focal": np.array([[FOCAL_MM]]), "pixelSize": np.array([[PIXEL_MM]]), "pp": np.array([PP])},
    )
    scipy.io.savemat(root / "Manhattan_Image_DB_Names.mat", {"Manhattan_Image_DB_Names": _names_cell(NAMES)})
    scipy.io.savemat(
        root / "ECCV_TrainingAndTestImageNumbers.mat",
        {
            "trainingSetIndex": np.array(TRAIN, dtype=np.uint8)[:, None],
            "testSetIndex": np.array(TEST, dtype=np.uint8)[:, None],
        },
    )
    for i, (name, (pitch, roll, yaw)) in enumerate(CAMERAS.items()):
        folder = root / name
        folder.mkdir()
        image = np.full((H, W, 3), 40 * i, dtype=np.uint8)
        assert cv2.imwrite(str(folder / f"{name}.jpg"), image)
        R = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (pitch, roll, yaw)))[0]
        scipy.io.savemat(
            folder / f"{name}GroundTruthVP_Orthogonal_CamParams.mat", {"vp_orthogonal": _yud_vp_from_rotation(R)}
        )
        raw = _yud_vp_from_rotation(R)
        raw[:, 1] = RAW_UP_YUP  # the raw vertical differs from the orthogonal one
        scipy.io.savemat(folder / f"{name}GroundTruthVP_CamParams.mat", {"vp": raw})
        lines = np.array([[11.0, 21.0], [31.0, 41.0], [1.0, 2.0], [3.0, 4.0]])  # 1-based, two segments
        scipy.io.savemat(
            folder / f"{name}LinesAndVP.mat",
            {
                "lines": lines.astype(np.uint16) if i == 1 else lines,
                "vp_association": np.array([[2], [3]], dtype=np.uint8),
            },
        )
    return root


def test_fake_splits_and_order(fake_yud):
    assert YorkUrbanDB(fake_yud).names == ["IMG_A", "IMG_B", "IMG_C"]
    train = YorkUrbanDB(fake_yud, split="train")
    assert train.names == ["IMG_C", "IMG_A"]  # the order of the split file
    assert [s.split for s in train] == ["train", "train"]
    test = YorkUrbanDB(fake_yud, split="test")
    assert test.names == ["IMG_B"]  # IMG_D is absent
    assert len(test) == 1 and test[0].split == "test" and test[-1].name == "IMG_B"
    assert "images=1" in repr(test)


def test_fake_known_answer(fake_yud):
    db = YorkUrbanDB(fake_yud)
    f = FOCAL_MM / PIXEL_MM
    K = torch.tensor([[f, 0.0, PP[0]], [0.0, f, PP[1]], [0.0, 0.0, 1.0]], dtype=torch.float64)
    for s in db:
        pitch, roll, yaw = CAMERAS[s.name]
        assert (s.height, s.width) == (H, W)
        assert s.image_path == fake_yud / s.name / f"{s.name}.jpg"
        assert s.K.dtype == torch.float64 and s.R.dtype == torch.float64
        torch.testing.assert_close(s.K, K)
        R = rotation_from_angles(*(torch.tensor([v], dtype=torch.float64) for v in (pitch, roll, yaw)))[0]
        torch.testing.assert_close(s.R, R)
        assert torch.linalg.det(s.R).item() == pytest.approx(1.0)
        assert s.pitch == pytest.approx(pitch, abs=1e-9)
        assert s.roll == pytest.approx(roll, abs=1e-9)
        assert s.focal == pytest.approx(500.0)
        assert s.fov_v == pytest.approx(math.degrees(2 * math.atan(H / 2 / f)))
        assert s.fov_h == pytest.approx(math.degrees(2 * math.atan(W / 2 / f)))
        torch.testing.assert_close(s.up, -R[:, 1])
        assert s.up[1] < 0
        zen = s.zenith[:2] / s.zenith[2]
        z_expected = (K @ s.up)[:2] / (K @ s.up)[2]
        torch.testing.assert_close(zen, z_expected)
        torch.testing.assert_close(s.vps, (K @ R).T)
        a, b, c = s.horizon.tolist()
        assert a * a + b * b == pytest.approx(1.0) and b >= 0
        # the horizon is the image of the world's horizontal directions
        for d in (R[:, 0], R[:, 2]):
            v = K @ d
            assert float(s.horizon @ v) == pytest.approx(0.0, abs=1e-9)
    # closed form for zero roll: a level line at y = c_y + f tan(pitch)
    a_ = db[0]
    torch.testing.assert_close(
        a_.horizon, torch.tensor([0.0, 1.0, -(PP[1] + f * math.tan(math.radians(10.0)))], dtype=torch.float64)
    )


def test_fake_raw_ground_truth(fake_yud):
    for s in YorkUrbanDB(fake_yud, ground_truth="raw"):
        expected_up = torch.tensor(RAW_UP_YUP * np.array([1.0, -1.0, 1.0]))
        torch.testing.assert_close(s.up, expected_up)
        torch.testing.assert_close(s.R.T @ s.R, torch.eye(3, dtype=torch.float64))
        assert torch.linalg.det(s.R).item() == pytest.approx(1.0)
        assert s.pitch == pytest.approx(math.degrees(math.atan(0.1)))
        assert s.roll == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="ground_truth"):
        YorkUrbanDB(fake_yud, ground_truth="best")


def test_fake_labelled_segments(fake_yud):
    for s in YorkUrbanDB(fake_yud):
        seg, assoc = load_labelled_segments(s.lines_path)
        assert seg.dtype == torch.float64 and seg.shape == (2, 2, 2)
        torch.testing.assert_close(
            seg, torch.tensor([[[10.0, 20.0], [30.0, 40.0]], [[0.0, 1.0], [2.0, 3.0]]], dtype=torch.float64)
        )
        assert assoc.tolist() == [1, 2]


def test_rotation_from_yud_vps_signs():
    R = rotation_from_angles(
        torch.tensor([7.0]).double(), torch.tensor([-4.0]).double(), torch.tensor([33.0]).double()
    )[0]
    vp = _yud_vp_from_rotation(R)
    for flip in ([1, 1, 1], [1, -1, 1], [1, 1, -1], [1, -1, -1]):
        torch.testing.assert_close(rotation_from_yud_vps(vp * np.array(flip)), R)
    flipped = rotation_from_yud_vps(vp * np.array([-1, 1, 1]))
    assert torch.linalg.det(flipped).item() == pytest.approx(1.0)
    torch.testing.assert_close(flipped[:, 1], R[:, 1])
    with pytest.raises(ValueError):
        rotation_from_yud_vps(np.eye(2))
    with pytest.raises(ValueError):
        rotation_from_yud_vps(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))


def test_errors(fake_yud, tmp_path):
    with pytest.raises(FileNotFoundError, match="root"):
        YorkUrbanDB(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="split"):
        YorkUrbanDB(fake_yud, split="val")
    (fake_yud / "ECCV_TrainingAndTestImageNumbers.mat").unlink()
    assert len(YorkUrbanDB(fake_yud)) == 3  # the split file is only needed to select a split
    assert YorkUrbanDB(fake_yud)[0].split is None
    with pytest.raises(FileNotFoundError, match="ECCV_TrainingAndTestImageNumbers"):
        YorkUrbanDB(fake_yud, split="train")
    (fake_yud / "IMG_B" / "IMG_BGroundTruthVP_Orthogonal_CamParams.mat").unlink()
    with pytest.raises(FileNotFoundError, match="IMG_BGroundTruthVP_Orthogonal"):
        YorkUrbanDB(fake_yud)
    (fake_yud / "Manhattan_Image_DB_Names.mat").unlink()
    with pytest.raises(FileNotFoundError, match="Manhattan_Image_DB_Names"):
        YorkUrbanDB(fake_yud)
    scipy.io.savemat(fake_yud / "cameraParameters.mat", {"focal": np.array([[5.0]])})
    with pytest.raises(ValueError, match="pixelSize"):
        YorkUrbanDB(fake_yud)
    (fake_yud / "cameraParameters.mat").unlink()
    with pytest.raises(FileNotFoundError, match="cameraParameters"):
        YorkUrbanDB(fake_yud)


def _segment_vp_angles(segments: torch.Tensor, vps: torch.Tensor) -> torch.Tensor:
    """Angle (deg, in [0, 90]) between each segment and the line from its midpoint to its homogeneous VP."""
    mid = segments.mean(1)
    t = segments[:, 1] - segments[:, 0]
    d = vps[:, :2] - mid * vps[:, 2:]
    cos = (t * d).sum(-1).abs() / (t.norm(dim=-1) * d.norm(dim=-1))
    return torch.rad2deg(torch.acos(cos.clamp(max=1.0)))


@pytest.mark.skipif(not (SHARED_YUD / "cameraParameters.mat").is_file(), reason="York Urban DB copy not present")
def test_shared_copy_ground_truth_is_consistent():
    db = YorkUrbanDB(SHARED_YUD, split="train")
    assert len(db) == 51
    assert len(YorkUrbanDB(SHARED_YUD)) == 51
    assert len(YorkUrbanDB(SHARED_YUD, split="test")) == 0
    all_err, vertical_err = [], []
    for s in db:
        assert (s.height, s.width) == (480, 640)
        assert s.focal == pytest.approx(674.918, abs=1e-3)
        torch.testing.assert_close(s.R.T @ s.R, torch.eye(3, dtype=torch.float64))
        assert torch.linalg.det(s.R).item() == pytest.approx(1.0)
        assert abs(s.roll) < 20 and abs(s.pitch) < 45
        seg, assoc = load_labelled_segments(s.lines_path)
        all_err.append(_segment_vp_angles(seg, s.vps[assoc]))
        vert = assoc == 1
        vertical_err.append(_segment_vp_angles(seg[vert], s.zenith.expand(int(vert.sum()), 3)))
    all_err, vertical_err = torch.cat(all_err), torch.cat(vertical_err)
    assert all_err.numel() > 1000
    assert all_err.median().item() < 1.0
    assert vertical_err.median().item() < 1.0
    # the raw vertical fits the labelled vertical segments at least as well
    raw_err = []
    for s in YorkUrbanDB(SHARED_YUD, split="train", ground_truth="raw"):
        seg, assoc = load_labelled_segments(s.lines_path)
        vert = assoc == 1
        raw_err.append(_segment_vp_angles(seg[vert], s.zenith.expand(int(vert.sum()), 3)))
    assert torch.cat(raw_err).median().item() < 1.0


def test_fake_published_horizon(fake_yud):
    for s in YorkUrbanDB(fake_yud):
        line = published_horizon(s)
        assert line.dtype == torch.float64 and line.shape == (3,)
        assert float(line[:2].norm()) == pytest.approx(1.0) and line[1] >= 0
        raw = scipy.io.loadmat(str(s.image_path.parent / f"{s.name}GroundTruthVP_CamParams.mat"))["vp"]
        for j in (0, 2):  # through both raw horizontal VPs
            v = s.K @ torch.diag(torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)) @ torch.as_tensor(raw[:, j])
            assert float(line @ v) == pytest.approx(0.0, abs=1e-9 * float(v.norm()))
        # the fake's raw horizontal VPs are the orthogonal ones: the two horizons coincide
        torch.testing.assert_close(line, s.horizon)


@pytest.mark.skipif(not (SHARED_YUD / "cameraParameters.mat").is_file(), reason="York Urban DB copy not present")
def test_shared_copy_published_horizon_differs_by_a_few_pixels():
    db = YorkUrbanDB(SHARED_YUD)
    published = torch.stack([published_horizon(s) for s in db])
    calibrated = torch.stack([s.horizon for s in db])
    px = horizon_error(published, calibrated, 480, 640) * 480
    assert 4.0 < float(px.median()) < 10.0  # about 7 px, as the dataset's README says
