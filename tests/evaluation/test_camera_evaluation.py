"""The evaluation's camera options: call arguments in weight specs, the principal-point and k1 errors, gravity priors
drawn from the truth, a set as one camera, and the worst-case sheets."""

import math

import cv2
import pytest

from ngp_kornia.evaluation import calibrate_method, evaluate, load_renders, run_interleaved
from ngp_kornia.evaluation.methods import call_arguments, gravity_prior, weights_and_config
from ngp_kornia.evaluation.sheets import sheet_name, worst_images
from ngp_kornia.evaluation.suite import main as suite_main
from ngp_kornia.training.synth.render import RenderConfig, render_dataset


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    root = tmp_path_factory.mktemp("lens")
    config = RenderConfig(fov_v=(50.0, 50.0), kinds={"street": 1.0}, k1_range=(-0.2, -0.1))
    render_dataset(root, 3, seed=3, size=(320, 240), config=config)
    return root


def test_call_arguments_are_not_settings():
    assert call_arguments("none:principal_point=estimate,shared_intrinsics=true,top_k=2") == {
        "principal_point": "estimate", "shared_intrinsics": True}
    assert weights_and_config("none:k1=estimate,top_k=2")[1].scoring.top_k == 2  # no k1 setting to refuse
    with pytest.raises(ValueError, match="gravity_noise"):
        call_arguments("none:gravity_noise=lots")


def test_gravity_priors_are_the_truth_plus_seeded_noise(renders):
    image = load_renders(renders)[0]
    assert gravity_prior(image, 0, 0.0) == pytest.approx((image.pitch, image.roll))
    one, again, other = (gravity_prior(image, s, 1.0) for s in (0, 0, 1))
    assert one == again and one != other
    assert abs(one[0] - image.pitch) < 5 and abs(one[1] - image.roll) < 5  # 5 sigma


def test_k1_and_principal_point_errors_are_scored(renders):
    images = load_renders(renders)
    assert all(-0.2 <= im.lens <= -0.1 for im in images)
    runs = run_interleaved({"plain": calibrate_method("none"), "lens": calibrate_method("none:k1=estimate")},
                           images, None)
    plain, lens = (evaluate(images, runs[name].estimates)["summary"] for name in ("plain", "lens"))
    assert plain["k1"]["median"] == pytest.approx(0.15, abs=0.05)  # the truth's own size: nothing estimated
    assert lens["k1"]["median"] < plain["k1"]["median"]
    assert plain["principal_point"]["mean"] == pytest.approx(0.0, abs=1e-3)  # centred renders, centred answer


def test_a_set_as_one_camera_and_its_worst_case_sheet(renders, tmp_path, capsys):
    images = load_renders(renders)
    run = run_interleaved({"one": calibrate_method("none:shared_intrinsics=true", 0, images)}, images, None)
    focals = [e.extra["focal"] for e in run["one"].estimates]
    assert max(focals) - min(focals) < 1e-4 * focals[0]
    assert suite_main(["--renders", str(renders), "--weights", "none:shared_intrinsics=true", "--seeds", "0",
                       "--quiet", "--sheets", str(tmp_path), "--sheet-count", "2"]) == 0
    sheet = cv2.imread(str(tmp_path / sheet_name("renders", "none:shared_intrinsics=true")))
    assert sheet is not None and sheet.shape[1] == 4 * 480  # two tiles and two empty ones in a row of four
    assert "shared" not in capsys.readouterr().err


def test_worst_images_put_failures_first():
    rows = [{"horizon": 0.01}, {"horizon": math.nan}, {"horizon": 0.2}, {}]
    assert worst_images(rows, 3) == [1, 3, 2]
