"""Tests of ngp_kornia.pipeline.segments: LSD line-segment detection returned as padded torch tensors (pixel-centre
convention)."""

import cv2
import numpy as np
import pytest
import torch
from kornia.core.exceptions import ShapeError

from ngp_kornia.io import ImageError
from ngp_kornia.pipeline import ParserConfig, SegmentSettings
from ngp_kornia.pipeline.segments import LineDetector, detect_segments, detect_segments_gray, pad_segments


def _rectangle(h, w, y0, y1, x0, x1, dtype=torch.float32):
    """Black (1, 3, h, w) image with a white filled rectangle over pixels [y0, y1] x [x0, x1] (inclusive)."""
    img = torch.zeros(1, 3, h, w, dtype=dtype)
    img[..., y0 : y1 + 1, x0 : x1 + 1] = 1.0
    return img


def _edges(seg, mask):
    """Split detected segments of an axis-aligned rectangle into horizontal and vertical ones."""
    s = seg[mask]
    d = (s[:, 1] - s[:, 0]).abs()
    return s[d[:, 0] > d[:, 1]], s[d[:, 0] <= d[:, 1]]


def _check_rectangle(seg, mask, x_lo, x_hi, y_lo, y_hi, tol):
    """Four edges: two horizontal at y_lo / y_hi spanning about [x_lo, x_hi], two vertical likewise."""
    assert int(mask.sum()) == 4
    hor, ver = _edges(seg, mask)
    assert len(hor) == 2 and len(ver) == 2
    ys = sorted(hor[:, :, 1].mean(1).tolist())
    xs = sorted(ver[:, :, 0].mean(1).tolist())
    assert ys == pytest.approx([y_lo, y_hi], abs=tol)
    assert xs == pytest.approx([x_lo, x_hi], abs=tol)
    # each edge is straight and lies within the rectangle's extent (plus the tolerance)
    assert (hor[:, 0, 1] - hor[:, 1, 1]).abs().max() < tol and (ver[:, 0, 0] - ver[:, 1, 0]).abs().max() < tol
    assert hor[:, :, 0].min() > x_lo - tol and hor[:, :, 0].max() < x_hi + tol
    assert ver[:, :, 1].min() > y_lo - tol and ver[:, :, 1].max() < y_hi + tol
    # and covers most of it
    assert ((hor[:, 1, 0] - hor[:, 0, 0]).abs() > 0.8 * (x_hi - x_lo)).all()
    assert ((ver[:, 1, 1] - ver[:, 0, 1]).abs() > 0.8 * (y_hi - y_lo)).all()


def test_detect_segments_rectangle_pixel_centres(dtype):
    # filled pixels 20..43: the edges lie between pixel centres, at 19.5 and 43.5
    img = _rectangle(64, 64, 20, 43, 20, 43, dtype=dtype)
    seg, mask = detect_segments(img)
    assert seg.shape == (1, 4, 2, 2) and mask.shape == (1, 4)
    assert seg.dtype == dtype and mask.dtype == torch.bool
    _check_rectangle(seg[0], mask[0], 19.5, 43.5, 19.5, 43.5, tol=0.35)


def test_detect_segments_non_square_rectangle():
    img = _rectangle(80, 120, 10, 49, 30, 99)
    seg, mask = detect_segments(img)
    _check_rectangle(seg[0], mask[0], 29.5, 99.5, 9.5, 49.5, tol=0.35)


def test_detect_segments_batch_padding():
    one = _rectangle(64, 64, 20, 43, 20, 43)
    two = _rectangle(64, 64, 10, 25, 5, 30) + _rectangle(64, 64, 40, 58, 35, 60)
    flat = torch.full((1, 3, 64, 64), 0.5)
    images = torch.cat([one, two, flat])
    seg, mask = detect_segments(images)
    assert seg.shape == (3, 8, 2, 2) and mask.shape == (3, 8)
    assert mask.sum(1).tolist() == [4, 8, 0]
    # valid entries first, padding after, padding zero
    assert mask[0, :4].all() and not mask[0, 4:].any()
    assert torch.equal(seg[0, 4:], torch.zeros(4, 2, 2)) and torch.equal(seg[2], torch.zeros(8, 2, 2))
    # the same segments as detecting each image on its own
    s0, m0 = detect_segments(one)
    torch.testing.assert_close(seg[0, :4], s0[0][m0[0]])


def test_detect_segments_flat_image_has_no_lines():
    seg, mask = detect_segments(torch.full((2, 3, 48, 64), 0.3))
    assert seg.shape[0] == 2 and seg.shape[2:] == (2, 2) and mask.shape == seg.shape[:2]
    assert not mask.any()


def test_detect_segments_downscaled_maps_back():
    # LSD runs on a 640x480 copy of a 1280x960 image; segments come back in input pixels
    img = _rectangle(960, 1280, 200, 599, 300, 999)
    seg, mask = detect_segments(img, SegmentSettings(working_size=640))
    # a missing half-pixel correction would put the edges about 0.75 px off
    _check_rectangle(seg[0], mask[0], 299.5, 999.5, 199.5, 599.5, tol=0.6)
    # min_length is in working-resolution pixels: the 200-px (working) edges pass 150, the 350-px ones only pass 300
    _, mask = detect_segments(img, SegmentSettings(working_size=640, min_length=300.0))
    assert int(mask.sum()) == 2


def test_detect_segments_smaller_than_working_size_unchanged():
    img = _rectangle(64, 64, 20, 43, 20, 43)
    a, ma = detect_segments(img, SegmentSettings(working_size=640))
    b, mb = detect_segments(img, SegmentSettings(working_size=64))
    assert torch.equal(a, b) and torch.equal(ma, mb)


def test_detect_segments_gray_longest_first_and_limits():
    gray = np.zeros((100, 120), np.uint8)
    gray[20:80, 10:110] = 255  # edges of 100 and 60 px
    seg = detect_segments_gray(gray)
    assert seg.dtype == np.float32 and seg.shape == (4, 2, 2)
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=-1)
    assert (np.diff(length) <= 0).all()  # longest first
    assert detect_segments_gray(gray, SegmentSettings(max_segments=2)).shape == (2, 2, 2)
    np.testing.assert_array_equal(detect_segments_gray(gray, SegmentSettings(max_segments=2)), seg[:2])
    assert detect_segments_gray(gray, SegmentSettings(min_length=80.0)).shape == (2, 2, 2)
    assert detect_segments_gray(np.zeros((50, 50), np.uint8)).shape == (0, 2, 2)


def test_detect_segments_gray_thin_lines_survive_downscaling():
    # 1-px lines in a 1920x1440 image, downscaled 3x to the 640 working size: an area-averaging resize keeps them
    # (faint), a point-sampling one drops every line that falls between its samples
    gray = np.zeros((1440, 1920), np.uint8)
    gray[300:1200, 600] = 255
    gray[450, 300:1500] = 255
    seg = detect_segments_gray(gray, SegmentSettings(working_size=640))
    assert len(seg) >= 2, "thin lines lost when downscaling (cv2.resize interpolation flag passed as dst)"
    xs = seg[..., 0].mean(1)
    ys = seg[..., 1].mean(1)
    assert (np.abs(xs - 600) < 5).any() and (np.abs(ys - 450) < 5).any()


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((32, 32), np.float32),
        np.zeros((32, 32), np.uint16),
        np.zeros((32, 32, 3), np.uint8),
        np.zeros((32,), np.uint8),
    ],
)
def test_detect_segments_gray_rejects_bad_input(bad):
    with pytest.raises(ValueError, match="uint8"):
        detect_segments_gray(bad)


def test_detect_segments_exception():
    with pytest.raises(ShapeError):
        detect_segments(torch.zeros(1, 1, 32, 32))
    with pytest.raises(ShapeError):
        detect_segments(torch.zeros(32, 32))
    with pytest.raises(TypeError, match="float"):
        detect_segments(torch.zeros(1, 3, 32, 32, dtype=torch.uint8))
    with pytest.raises(TypeError):
        detect_segments([np.zeros((32, 32, 3), np.uint8)])
    with pytest.raises(ImageError):
        detect_segments(np.zeros((32, 32, 2), np.uint8))


def test_detect_segments_accepts_every_image_form(tmp_path):
    # a tensor, an unbatched tensor, an 8-bit array, a greyscale array and a file give the same segments
    img = _rectangle(64, 80, 20, 43, 10, 60)
    ref, ref_mask = detect_segments(img)
    rgb = (img[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy()
    path = tmp_path / "rect.png"
    cv2.imwrite(str(path), rgb)
    for form in (img[0], rgb, rgb[..., 0], str(path), path):
        seg, mask = detect_segments(form)
        assert seg.shape == ref.shape and seg.dtype == torch.float32
        assert torch.equal(seg, ref) and torch.equal(mask, ref_mask)


def test_detect_segments_settings_come_from_the_config():
    gray = np.zeros((100, 120), np.uint8)
    gray[20:80, 10:110] = 255
    cfg = SegmentSettings(max_segments=3)
    assert detect_segments(gray, cfg)[1].sum() == 3 == len(detect_segments_gray(gray, cfg))
    assert detect_segments(np.zeros((100, 120), np.uint8))[0].shape == (1, 0, 2, 2)


def test_line_detector_module():
    det = LineDetector(SegmentSettings(working_size=640, min_length=10.0, max_segments=2))
    assert len(list(det.parameters())) == 0
    seg, mask = det(_rectangle(64, 64, 20, 43, 20, 43))
    assert seg.shape == (1, 2, 2, 2) and mask.all()


def test_pad_segments():
    a = np.arange(8, dtype=np.float32).reshape(2, 2, 2)
    b = torch.ones(3, 2, 2, dtype=torch.float64)
    seg, mask = pad_segments([a, np.zeros((0, 2, 2)), b])
    assert seg.shape == (3, 3, 2, 2) and seg.dtype == torch.float32
    assert mask.tolist() == [[True, True, False], [False, False, False], [True, True, True]]
    torch.testing.assert_close(seg[0, :2], torch.from_numpy(a))
    assert torch.equal(seg[0, 2], torch.zeros(2, 2)) and torch.equal(seg[1], torch.zeros(3, 2, 2))
    torch.testing.assert_close(seg[2], torch.ones(3, 2, 2))
    # like= sets dtype and device
    seg, mask = pad_segments([a], like=torch.zeros(1, dtype=torch.float64))
    assert seg.dtype == torch.float64 and mask.device == seg.device
    # all empty, or no images at all
    seg, mask = pad_segments([np.zeros((0, 2, 2)), np.zeros((0, 2, 2))])
    assert seg.shape == (2, 0, 2, 2) and mask.shape == (2, 0)
    seg, mask = pad_segments([])
    assert seg.shape == (0, 0, 2, 2) and mask.shape == (0, 0)


def test_fast_line_detector_finds_the_rectangle():
    # FastLineDetector puts edges on Canny's edge pixels, up to half a pixel off LSD's sub-pixel ones
    img = _rectangle(80, 120, 10, 49, 30, 99)
    seg, mask = detect_segments(img, SegmentSettings(detector="fld"))
    _check_rectangle(seg[0], mask[0], 29.5, 99.5, 9.5, 49.5, tol=1.0)
    assert int(LineDetector(SegmentSettings(detector="fld"))(img)[1].sum()) == 4


def test_unknown_detector_names_the_choices():
    with pytest.raises(ValueError, match="SegmentSettings.detector must be one of lsd, fld, got 'hough'"):
        SegmentSettings(detector="hough")


def test_parser_config_selects_the_detector():
    from ngp_kornia import calibrate
    from ngp_kornia.training.synth.render import render_scene

    image = render_scene(3, size=(320, 240)).image
    lsd, fld = calibrate(image), calibrate(image, config=ParserConfig(segments=SegmentSettings(detector="fld")))
    assert bool(lsd.valid) and bool(fld.valid) and float(lsd.focal) != float(fld.focal)


def _slanted_bar(h: int, w: int, top: tuple[float, float], bottom: tuple[float, float]) -> np.ndarray:
    """A white quadrilateral from ``top`` to ``bottom`` (x, y), 12 pixels wide, on a black uint8 image."""
    (x0, y0), (x1, y1) = top, bottom
    polygon = np.array([[x0, y0], [x0 + 12, y0], [x1 + 12, y1], [x1, y1]], np.int32)
    return cv2.fillPoly(np.zeros((h, w), np.uint8), [polygon], 255)


def _one_piece(**kw) -> SegmentSettings:
    return SegmentSettings(line_strips=1, **kw)


def test_strips_give_the_rectangle_whose_edges_cross_the_cuts():
    # 480 rows in two strips are cut at row 240: both vertical edges cross it and come back as one segment each;
    # the horizontal edges lie in the strips' overlap (rows 230-250) and come back once, not twice
    img = _rectangle(480, 640, 235, 247, 150, 499)
    img = img + _rectangle(480, 640, 40, 439, 560, 599)
    seg, mask = detect_segments(img, SegmentSettings(line_strips=2))
    whole, whole_mask = detect_segments(img, _one_piece())
    assert int(mask.sum()) == int(whole_mask.sum()) == 8
    assert _farthest_match(seg[0][mask[0]].numpy(), whole[0][whole_mask[0]].numpy()) < 0.5


def _farthest_match(a: np.ndarray, b: np.ndarray) -> float:
    """How far (pixels, the worse endpoint) the segment of ``a`` farthest from every segment of ``b`` is from its
    nearest one, either way round."""
    ends = lambda s: np.abs(a[:, None] - s[None]).max(-1).max(-1)  # noqa: E731
    return float(np.minimum(ends(b), ends(b[:, ::-1])).min(1).max())


@pytest.mark.parametrize("strips", [2, 3])
def test_a_slanted_line_across_the_cuts_is_one_segment(strips):
    gray = _slanted_bar(600, 400, (100, 30), (260, 570))
    seg = detect_segments_gray(gray, SegmentSettings(line_strips=strips))
    whole = detect_segments_gray(gray, _one_piece())
    assert len(seg) == len(whole) == 4  # the bar's two long sides and its two short ends
    lengths = lambda s: np.sort(np.linalg.norm(s[:, 1] - s[:, 0], axis=-1))  # noqa: E731
    np.testing.assert_allclose(lengths(seg), lengths(whole), atol=1.0)


def test_strips_do_not_depend_on_the_threads_that_run_them():
    from ngp_kornia.pipeline.segments import line_workers
    from ngp_kornia.training.synth.render import render_scene

    gray = cv2.cvtColor(render_scene(5, size=(640, 480)).image, cv2.COLOR_RGB2GRAY)
    config = SegmentSettings(line_strips=3)
    with line_workers(1):
        alone = detect_segments_gray(gray, config)
    with line_workers(3):
        together = detect_segments_gray(gray, config)
    assert len(alone) > 50 and np.array_equal(alone, together)


def test_short_images_are_detected_in_one_piece():
    # 64 rows cannot hold two strips of at least 40 rows: the whole image is the one strip
    img = _rectangle(64, 64, 20, 43, 20, 43)
    a, _ = detect_segments(img, SegmentSettings(line_strips=4))
    b, _ = detect_segments(img, _one_piece())
    assert torch.equal(a, b)


def test_strips_work_in_a_forked_process():
    # the parent's LSD threads do not exist in a forked child; the child must start its own, not wait for them
    import multiprocessing

    gray = _slanted_bar(480, 640, (100, 30), (260, 450))
    expected = detect_segments_gray(gray)  # the parent's pool now exists
    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        got = pool.apply_async(detect_segments_gray, (gray,)).get(timeout=60)
    assert np.array_equal(got, expected)


@pytest.mark.parametrize("bad", [0, 17, 1.5, True])
def test_line_strips_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="SegmentSettings.line_strips must be an integer in \\[1, 16\\]"):
        SegmentSettings(line_strips=bad)


def test_strips_find_the_lines_of_the_whole_image():
    # LSD's region growing and significance test see a strip, not the image, so a few segments differ; strips on
    # the image's own resampling grid keep almost all of them (off the grid, a quarter of the length moves)
    from ngp_kornia.training.synth.render import render_scene

    gray = cv2.cvtColor(render_scene(7, size=(640, 486)).image, cv2.COLOR_RGB2GRAY)
    whole = detect_segments_gray(gray, _one_piece(max_segments=16384))
    strips = detect_segments_gray(gray, SegmentSettings(line_strips=2, max_segments=16384))
    ends = lambda s: np.abs(whole[:, None] - s[None]).max(-1).max(-1)  # noqa: E731
    found = np.minimum(ends(strips), ends(strips[:, ::-1])).min(1) < 1.0
    length = np.linalg.norm(whole[:, 1] - whole[:, 0], axis=-1)
    assert length[found].sum() / length.sum() > 0.95


def test_strips_run_on_the_process_share_of_the_cores():
    import ngp_kornia.pipeline.segments as detect
    from ngp_kornia.pipeline.segments import strip_threads
    from ngp_kornia.threads import usable_cores

    with detect.line_workers(1):  # ngp predict's processes each get their share
        assert strip_threads(2) == 1
    with detect.line_workers(8):
        assert strip_threads(2) == min(2, usable_cores())  # never more threads than strips, nor than cores


def test_calls_from_several_threads_share_the_strip_threads():
    # a server may calibrate in many threads at once: each call's strips still come back whole and in order
    from concurrent.futures import ThreadPoolExecutor

    from ngp_kornia.training.synth.render import render_scene

    grays = [cv2.cvtColor(render_scene(seed, size=(640, 480)).image, cv2.COLOR_RGB2GRAY) for seed in range(4)]
    expected = [detect_segments_gray(g) for g in grays]
    with ThreadPoolExecutor(4) as callers:
        got = list(callers.map(detect_segments_gray, grays * 3, timeout=120))
    assert all(np.array_equal(a, b) for a, b in zip(got, expected * 3, strict=True))


def test_calls_from_many_threads_at_once_get_the_segments_of_one_call():
    # the strips of every call share one pool: calls that find it busy with other calls' strips still finish, and
    # the segments never depend on which thread detected a strip
    from concurrent.futures import ThreadPoolExecutor

    from ngp_kornia.training.synth.render import render_scene

    gray = cv2.cvtColor(render_scene(5, size=(640, 480)).image, cv2.COLOR_RGB2GRAY)
    expected = detect_segments_gray(gray)
    with ThreadPoolExecutor(8) as callers:
        found = list(callers.map(lambda _: detect_segments_gray(gray), range(16), timeout=120))
    assert all(np.array_equal(got, expected) for got in found)


@pytest.mark.parametrize(
    ("image", "settings"),
    [
        (np.dstack([_slanted_bar(480, 640, (100, 30), (260, 450))] * 3), SegmentSettings()),  # two strips
        (np.dstack([_slanted_bar(480, 640, (100, 30), (260, 450))] * 3), _one_piece()),
        (_rectangle(96, 128, 20, 60, 30, 90), SegmentSettings()),  # a tensor, too short for strips
        (torch.zeros(0, 3, 96, 128), SegmentSettings()),  # an empty batch
    ],
)
def test_a_job_given_to_line_detection_runs_once_and_changes_no_segment(image, settings):
    # calibrate() converts a photo's pixels while its thread would wait for the last strip: that job runs exactly
    # once however the lines are found, and the segments are those found without it
    from ngp_kornia.pipeline.segments import line_workers

    calls = []
    with line_workers(2):
        seg, mask = detect_segments(image, settings, meanwhile=lambda: calls.append(1))
    plain, plain_mask = detect_segments(image, settings)
    assert calls == [1]
    assert torch.equal(seg, plain) and torch.equal(mask, plain_mask)
