import math
import os
from pathlib import Path

import pytest
import torch

from ngp_kornia.data import NYUVP, nyu_up
from ngp_kornia.metrics import horizon_error
from tests.nyu_files import write_fake_nyu

SHARED_NYU = Path(os.environ.get("NYU_VP_ROOT", "/work/shared/data/NYU-VP"))


@pytest.fixture()
def fake_nyu(tmp_path: Path) -> Path:
    return write_fake_nyu(tmp_path)


def test_reads_a_scene_with_its_horizon_truth(fake_nyu):
    s = NYUVP(fake_nyu).scene(0)
    assert (s.height, s.width) == (480, 640) and s.name == "nyu-0000"
    assert s.segments.shape == (3 + 36, 2, 2) and s.vps.shape == (3, 3)
    assert [len(x) for x in s.labelled] == [1, 2, 0]
    assert s.labelled[1][1].tolist() == [[9.0, 10.0], [11.0, 12.0]]
    assert s.vertical == 1
    assert s.pitch == pytest.approx(-10.0, abs=1e-6) and s.roll == pytest.approx(3.0, abs=1e-6)
    assert float(s.up[1]) < 0 and float(s.horizon[:2].norm()) == pytest.approx(1.0)
    # the horizon is K^-T up: it passes through the two horizontal VPs
    for j in (0, 2):
        assert abs(float(s.horizon @ s.vps[j])) < 1e-6
    assert s.fov_v == pytest.approx(math.degrees(2 * math.atan(240 / 519.470)))


def test_a_scene_without_a_steep_vanishing_point_has_no_horizon_truth(fake_nyu):
    s = NYUVP(fake_nyu).scene(1)
    assert s.vertical is None and s.up is None and s.horizon is None and s.pitch is None


def test_lists_scenes_and_reads_a_range(fake_nyu):
    assert NYUVP(fake_nyu).scenes == [0, 1]
    assert [s.index for s in NYUVP(fake_nyu, [1])] == [1]
    with pytest.raises(FileNotFoundError, match="vps_0007"):
        NYUVP(fake_nyu, [7])[0]


def test_bad_files_are_named(fake_nyu):
    (fake_nyu / "data" / "vps_0000.csv").write_text("idx X Y\n0 1.0 nan\n")
    with pytest.raises(ValueError, match="vps_0000.csv, line 2: a value is not finite"):
        NYUVP(fake_nyu).scene(0)


def test_vertical_needs_a_steep_direction():
    index, up = nyu_up(torch.tensor([[2000.0, 250.0, 1.0], [330.0, 800.0, 1.0]], dtype=torch.float64))
    assert index is None and up is None  # 800 px lies only ~48 degrees below the axis


@pytest.mark.skipif(not SHARED_NYU.is_dir(), reason="NYU-VP not available")
def test_real_set_matches_its_readme():
    reader = NYUVP(SHARED_NYU)
    assert len(reader) == 1224
    without = [s.index for s in reader if s.up is None]
    assert len(without) == 23
    s = reader.scene(0)
    assert len(s.segments) == 261 and len(s.vps) == 3
    # the labelled segments point at their vanishing point
    from ngp_kornia.geometry.vp import segment_vp_angle

    angles = [segment_vp_angle(seg[None], s.vps[j][None, None])[0, 0] for j, seg in enumerate(s.labelled)]
    assert float(torch.cat(angles).median()) < 1.0
    assert float(horizon_error(s.horizon[None], s.horizon[None], 480, 640)[0]) == 0.0
