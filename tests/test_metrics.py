import math

import pytest
import torch

from ngp_kornia.geometry.camera import (
    horizon_from_zenith,
    intrinsics_matrix,
    pitch_roll_from_up,
    rotation_from_angles,
    up_from_rotation,
    zenith_from_up,
)
from ngp_kornia.metrics import (
    angle_error_between_rotations,
    fov_error,
    horizon_auc,
    horizon_error,
    pitch_error,
    roll_error,
    summarize,
    up_vector_error,
)

BATCHES = [1, 2, 7]


def _random_camera(b: int, seed: int = 0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    pitch = (torch.rand(b, generator=g, dtype=dtype) - 0.5) * 60
    roll = (torch.rand(b, generator=g, dtype=dtype) - 0.5) * 40
    yaw = (torch.rand(b, generator=g, dtype=dtype) - 0.5) * 180
    focal = 300 + 700 * torch.rand(b, generator=g, dtype=dtype)
    return pitch, roll, yaw, focal


@pytest.mark.parametrize("b", BATCHES)
def test_identical_inputs_give_zero(b, dtype):
    pitch, roll, yaw, focal = _random_camera(b, dtype=dtype)
    R = rotation_from_angles(pitch, roll, yaw)
    up = up_from_rotation(R)
    K = intrinsics_matrix(focal, torch.tensor([319.5, 239.5]))
    horizon = horizon_from_zenith(K, zenith_from_up(K, up))
    for err in (
        up_vector_error(up, up.clone()),
        pitch_error(pitch, pitch.clone()),
        roll_error(roll, roll.clone()),
        fov_error(focal, focal.clone()),
        horizon_error(horizon, horizon.clone(), 480, 640),
    ):
        assert err.shape == (b,)
        assert err.dtype == dtype
        assert torch.equal(err, torch.zeros_like(err))
    rot = angle_error_between_rotations(R, R.clone())
    assert rot.shape == (b,)
    torch.testing.assert_close(rot, torch.zeros_like(rot), atol=1e-5, rtol=0)


@pytest.mark.parametrize("b", BATCHES)
def test_up_vector_error_known_angles(b):
    angles = torch.linspace(0.0, 180.0, b, dtype=torch.float64)
    t = torch.deg2rad(angles)
    gt = torch.tensor([[0.0, -1.0, 0.0]], dtype=torch.float64).expand(b, 3)
    pred = torch.stack([torch.sin(t), -torch.cos(t), torch.zeros_like(t)], -1) * 3.0  # length does not matter
    torch.testing.assert_close(up_vector_error(pred, gt), angles)
    torch.testing.assert_close(up_vector_error(gt, pred), angles)


def test_up_vector_error_small_angle_precision_float32():
    t = math.radians(0.001)
    pred = torch.tensor([[math.sin(t), -math.cos(t), 0.0]])
    gt = torch.tensor([[0.0, -1.0, 0.0]])
    torch.testing.assert_close(up_vector_error(pred, gt), torch.tensor([0.001]), atol=1e-6, rtol=1e-3)


def test_up_vector_error_is_sign_sensitive_and_finite_for_zero_vectors():
    gt = torch.tensor([[0.0, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]])
    pred = torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    err = up_vector_error(pred, gt)
    torch.testing.assert_close(err, torch.tensor([180.0, 90.0, 90.0]))
    assert torch.isfinite(err).all()


def test_up_vector_error_matches_pitch_for_pure_pitch():
    pitch = torch.tensor([0.0, 12.0, -7.5], dtype=torch.float64)
    up_pred = up_from_rotation(rotation_from_angles(pitch, torch.zeros(3, dtype=torch.float64)))
    zero = torch.zeros(3, dtype=torch.float64)
    up_gt = up_from_rotation(rotation_from_angles(zero, zero))
    torch.testing.assert_close(up_vector_error(up_pred, up_gt), pitch.abs())
    p, _ = pitch_roll_from_up(up_pred)
    torch.testing.assert_close(pitch_error(p, torch.zeros_like(p)), pitch.abs())


def test_roll_of_ten_degrees_gives_ten():
    zero = torch.zeros(1, dtype=torch.float64)
    up_a = up_from_rotation(rotation_from_angles(zero, zero))
    up_b = up_from_rotation(rotation_from_angles(zero, zero + 10.0))
    _, roll_a = pitch_roll_from_up(up_a)
    _, roll_b = pitch_roll_from_up(up_b)
    torch.testing.assert_close(roll_error(roll_b, roll_a), torch.tensor([10.0], dtype=torch.float64))
    torch.testing.assert_close(up_vector_error(up_b, up_a), torch.tensor([10.0], dtype=torch.float64))


@pytest.mark.parametrize("b", BATCHES)
def test_roll_error_wraps(b):
    gt = torch.full((b,), 175.0)
    pred = torch.linspace(-175.0, -165.0, b)
    expected = (pred + 360.0) - gt
    torch.testing.assert_close(roll_error(pred, gt), expected)
    torch.testing.assert_close(roll_error(gt, pred), expected)
    assert roll_error(torch.tensor([90.0]), torch.tensor([-90.0])).item() == pytest.approx(180.0)
    assert roll_error(torch.tensor([370.0]), torch.tensor([5.0])).item() == pytest.approx(5.0)


def test_pitch_and_fov_error_known_values():
    torch.testing.assert_close(
        pitch_error(torch.tensor([5.0, -5.0]), torch.tensor([-5.0, 0.0])), torch.tensor([10.0, 5.0])
    )
    torch.testing.assert_close(
        fov_error(torch.tensor([60.0, 40.0]), torch.tensor([45.0, 45.0])), torch.tensor([15.0, 5.0])
    )


@pytest.mark.parametrize("b", BATCHES)
def test_angle_error_between_rotations_known(b):
    pitch, roll, yaw, _ = _random_camera(b, seed=3)
    R = rotation_from_angles(pitch, roll, yaw)
    delta = torch.linspace(0.0, 170.0, b, dtype=torch.float64)
    Rz = rotation_from_angles(torch.zeros_like(delta), delta)  # rotation by delta about the optical axis
    torch.testing.assert_close(angle_error_between_rotations(Rz @ R, R), delta)


def test_angle_error_between_rotations_small_angle_float32():
    # a hundredth of a degree still reads as one in float32 (the sine comes from the skew part, not acos)
    R = rotation_from_angles(torch.tensor([12.0]), torch.tensor([-3.0]), torch.tensor([40.0]))
    Rz = rotation_from_angles(torch.zeros(1), torch.tensor([0.01]))
    torch.testing.assert_close(angle_error_between_rotations(Rz @ R, R), torch.tensor([0.01]), atol=1e-4, rtol=0)


def test_angle_error_between_rotations_finite_for_approximate_rotations():
    # matrices that are rotations only to 1e-3 (an average, a fit) still get a finite angle near the true one: a
    # 1e-3 change of the entries moves it by about 0.06 degrees
    R = rotation_from_angles(torch.tensor([5.0, 0.0]), torch.tensor([2.0, 0.0]))
    level = rotation_from_angles(torch.zeros(2), torch.zeros(2))
    noisy = R + 1e-3 * torch.randn(2, 3, 3, generator=torch.Generator().manual_seed(0))
    err = angle_error_between_rotations(noisy, level)
    assert torch.isfinite(err).all()
    torch.testing.assert_close(err, angle_error_between_rotations(R, level), atol=0.2, rtol=0)


@pytest.mark.parametrize("b", BATCHES)
def test_horizon_shifted_by_a_tenth_of_the_height(b):
    pitch, roll, yaw, focal = _random_camera(b, seed=1)
    K = intrinsics_matrix(focal, torch.tensor([319.5, 239.5], dtype=torch.float64))
    up = up_from_rotation(rotation_from_angles(pitch, roll, yaw))
    gt = horizon_from_zenith(K, zenith_from_up(K, up))
    shifted = gt.clone()
    shifted[:, 2] -= gt[:, 1] * 48.0  # a x + b (y - 48) + c = 0: moved 48 px (= h / 10) down
    tenth = torch.full((b,), 0.1, dtype=torch.float64)
    torch.testing.assert_close(horizon_error(shifted, gt, 480, 640), tenth)
    torch.testing.assert_close(horizon_error(gt, shifted, 480, 640), tenth)


def test_horizon_error_takes_the_larger_border_distance():
    gt = torch.tensor([[0.0, 1.0, -100.0]])  # y = 100
    # through (-0.5, 100) and (99.5, 120): tilted, 0 px off on the left and 20 px off on the right
    a, b = -20.0, 100.0
    pred = torch.tensor([[a, b, -(a * -0.5 + b * 100.0)]])
    torch.testing.assert_close(horizon_error(pred, gt, 200, 100), torch.tensor([0.1]))
    # per-image sizes as tensors
    heights, widths = torch.tensor([200.0, 100.0]), torch.tensor([100, 100])
    err = horizon_error(pred.expand(2, 3), gt.expand(2, 3), heights, widths)
    torch.testing.assert_close(err, torch.tensor([0.1, 0.2]))


def test_horizon_error_scale_and_sign_invariant():
    gt = torch.tensor([[0.1, 1.0, -200.0]])
    pred = torch.tensor([[0.1, 1.0, -230.0]])
    e = horizon_error(pred, gt, 300, 400)
    torch.testing.assert_close(horizon_error(-5.0 * pred, 0.3 * gt, 300, 400), e)
    torch.testing.assert_close(e, torch.tensor([30.0 / 300.0]))


def test_horizon_auc_known_sets():
    assert horizon_auc(torch.zeros(5)).item() == pytest.approx(1.0)
    assert horizon_auc(torch.tensor([0.25, 0.3, 1.0])).item() == pytest.approx(0.0)
    assert horizon_auc(torch.tensor([0.0, 0.125, 0.3])).item() == pytest.approx(0.5)
    assert horizon_auc([0.05, 0.1]).item() == pytest.approx((0.8 + 0.6) / 2)
    assert horizon_auc(torch.tensor([0.1]), max_error=0.2).item() == pytest.approx(0.5)
    # failures count as errors beyond the range
    assert horizon_auc(torch.tensor([0.0, float("nan"), float("inf")])).item() == pytest.approx(1.0 / 3.0)


@pytest.mark.parametrize("n", [1, 3, 50])
def test_horizon_auc_equals_integral_of_empirical_cdf(n):
    g = torch.Generator().manual_seed(n)
    errors = torch.rand(n, generator=g, dtype=torch.float64) * 0.4
    m = 0.25
    # the empirical CDF is a step function: integrate it exactly between its breakpoints
    knots = torch.cat(
        [
            torch.tensor([0.0], dtype=torch.float64),
            errors.clamp(max=m).sort().values,
            torch.tensor([m], dtype=torch.float64),
        ]
    )
    area = 0.0
    for lo, hi in zip(knots[:-1].tolist(), knots[1:].tolist(), strict=True):
        cdf = float((errors <= lo).double().mean())
        area += cdf * (hi - lo)
    assert horizon_auc(errors, m).item() == pytest.approx(area / m, abs=1e-12)
    # and a dense Riemann sum agrees
    grid = torch.linspace(0, m, 200001, dtype=torch.float64)
    cdf = (errors[None, :] <= grid[:, None]).double().mean(1)
    assert horizon_auc(errors, m).item() == pytest.approx(float(torch.trapezoid(cdf, grid)) / m, abs=1e-4)


def test_summarize():
    s = summarize(torch.tensor([3.0, 1.0, 2.0]))
    assert s == {"mean": 2.0, "median": 2.0, "count": 3}
    assert summarize([1.0, 2.0, 4.0, 10.0])["median"] == 3.0
    assert math.isnan(summarize(torch.tensor([1.0, float("nan")]))["mean"])
    assert summarize(torch.zeros(0))["count"] == 0


def test_shape_and_type_errors():
    with pytest.raises(ValueError):
        up_vector_error(torch.zeros(2, 3), torch.zeros(3, 3))
    with pytest.raises(ValueError):
        up_vector_error(torch.zeros(2, 4), torch.zeros(2, 4))
    with pytest.raises(ValueError):
        up_vector_error(torch.zeros(3), torch.zeros(3))
    with pytest.raises(TypeError):
        up_vector_error([[0.0, -1.0, 0.0]], torch.zeros(1, 3))
    with pytest.raises(TypeError):
        up_vector_error(torch.zeros(1, 3, dtype=torch.int64), torch.zeros(1, 3))
    with pytest.raises(ValueError):
        pitch_error(torch.zeros(2), torch.zeros(3))
    with pytest.raises(ValueError):
        roll_error(torch.zeros(2, 1), torch.zeros(2, 1))
    with pytest.raises(ValueError):
        fov_error(torch.zeros(2), torch.zeros(1))
    with pytest.raises(ValueError):
        angle_error_between_rotations(torch.eye(3)[None], torch.eye(3)[None].expand(2, 3, 3))
    with pytest.raises(ValueError):
        horizon_error(torch.zeros(2, 3), torch.zeros(1, 3), 480, 640)
    with pytest.raises(ValueError):
        horizon_error(torch.zeros(2, 2), torch.zeros(2, 2), 480, 640)
    with pytest.raises(ValueError):
        horizon_error(torch.zeros(2, 3), torch.zeros(2, 3), torch.tensor([480.0, 480.0, 480.0]), 640)
    with pytest.raises(ValueError):
        horizon_error(torch.zeros(2, 3), torch.zeros(2, 3), 0, 640)
    with pytest.raises(TypeError):
        horizon_error(torch.zeros(2, 3), torch.zeros(2, 3), "480", 640)
    with pytest.raises(ValueError):
        horizon_auc(torch.zeros(2, 2))
    with pytest.raises(ValueError):
        horizon_auc(torch.zeros(0))
    with pytest.raises(ValueError):
        horizon_auc(torch.tensor([-0.1]))
    with pytest.raises(ValueError):
        horizon_auc(torch.tensor([0.1]), max_error=0.0)
    with pytest.raises(TypeError):
        horizon_auc("0.1")
