"""Every public function of pipeline/ in float32 and float64 on every available device: outputs on the input's
device, floating outputs in its dtype (or in the dtype a function documents, e.g. float64 for the exports) and
finite, and, where the answer does not branch on rounding, the float64 CPU values; the functions the docs call
differentiable pass gradcheck in float64; a batch gives each image what it gets alone."""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
import torch
from torch.autograd import gradcheck

import ngp_kornia.pipeline as pipeline_room
from ngp_kornia.geometry import FrameCandidates, coefficient_from_pseudo, coefficient_to_pseudo
from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.pipeline import (
    answer,
    camera_export,
    camera_model,
    candidates,
    constants,
    distortion,
    evidence,
    frame_search,
    gravity,
    horizon,
    horizon_support,
    line_kernel,
    parser,
    polish,
    principal_point,
    runner,
    shared_camera,
    trust,
    trust_features,
    upright_check,
)
from ngp_kornia.pipeline import segments as segments_stage
from ngp_kornia.pipeline.priors import Priors
from ngp_kornia.pipeline.settings import DistortionSettings, SamplingSettings, ScoringSettings, SharedSettings
from ngp_kornia.training.synth.render import render_scene
from ngp_kornia.training.synth.render_config import RenderConfig
from tests.rooms import check_output, inputs, public_functions, tensors

F64 = torch.float64
#: the camera options asked for as estimates
ESTIMATES = Priors(principal_point="estimate", k1="estimate")


def _upright_net(x):
    torch.manual_seed(0)
    return UprightNet(size=32, width=4).to(x.device).eval()


def _lines_net(x):
    torch.manual_seed(0)
    return UprightLinesNet(width=8, members=2).to(x.device).eval()


def _evidence_net(x):
    torch.manual_seed(0)
    return LineEvidenceNet(width=8, context=4).to(x.device, x.dtype).eval()


def _found(x):
    return horizon.search_horizon(x.cal, x.segments, x.mask)


def _shared_focal(x):
    focals = torch.linspace(200.0, 400.0, 9, dtype=x.dtype, device=x.device)
    support = shared_camera.focal_support(x.cal.K, x.cal.R, x.segments, x.mask, focals)
    return shared_camera.joint_focal(support, focals, x.cal.valid, bootstrap=20)


class _FixedSearch(frame_search.FrameSearch):
    """A frame search that answers the scenes' calibration whatever it is given: the camera model's own arithmetic
    (moving the segments and the answer) on every dtype."""

    def __init__(self, x):
        super().__init__(pipeline_room.ParserConfig())
        self.x = x

    def __call__(self, view, priors, centre_std=None):
        x = self.x
        cal = answer.calibration_from_camera(x.cal.K, x.cal.R, x.cal.score, x.cal.valid, x.height, x.width)
        return frame_search.Search(cal, None, None, None, None)


def _run(x):
    """A call on the geometric path, with the scenes' true focal length per image (one prior per image)."""
    return runner.Run(pipeline_room.NeuralGeometricParser(), 0, Priors(focal=[300.0, 320.0]))


def _one_input(x, i):
    """Image ``i`` of the scenes as the runner reads a tensor, with its segments."""
    return runner.Input(x.images[i : i + 1], x.segments[i : i + 1], x.mask[i : i + 1], None, Priors(focal=300.0))


@lru_cache(maxsize=1)
def _photos() -> torch.Tensor:
    """Two rendered photos of one camera, (2, 3, 120, 160) float64 (whose lines the shared camera measures)."""
    config = RenderConfig(fov_v=(50.0, 50.0), kinds={"street": 1.0})
    scenes = [render_scene(seed, (160, 120), config).image for seed in (2, 5)]
    return torch.stack([torch.from_numpy(image).permute(2, 0, 1) for image in scenes]).double() / 255


def _with_options(x):
    """The scenes' calibration with an estimated principal point's deviation and a distortion."""
    cal = replace(x.cal, principal_point_std=torch.ones_like(x.cal.principal_point))
    return replace(cal, camera=cal.camera.replace(lens=torch.full_like(cal.focal, -0.1)))


def _bent(x):
    """The scenes' cameras with a lens distortion."""
    return x.cal.camera.replace(lens=torch.full_like(x.cal.focal, -0.1))


def _frames_r(x):
    return x.trace.frames.R


#: module.function -> (the call on the inputs, options for check_output: tol, float_dtype)
CASES = {
    "answer.calibration_from_camera": (
        lambda x: answer.calibration_from_camera(x.cal.K, x.cal.R, x.cal.score, x.cal.valid, x.height, x.width), {}),
    "answer.level_answer": (
        lambda x: answer.level_answer(x.cal, torch.tensor([True, False], device=x.device), 60.0), {}),
    "answer.topk_calibration": (
        lambda x: answer.topk_calibration(x.trace.final_frames, x.trace.final_scores, x.height, x.width,
                                          ScoringSettings()), {"tol": False}),  # ties in the top k
    "camera_export.colmap_camera": (
        lambda x: torch.tensor(camera_export.colmap_camera(_bent(x)[0], "RADIAL")["params"], dtype=F64),
        {"float_dtype": F64}),
    "camera_export.kornia_camera": (
        lambda x: (lambda c: (c.intrinsics, c.extrinsics))(camera_export.kornia_camera(x.cal.K, x.cal.R,
                                                                                       x.cal.image_size)), {}),
    "camera_export.opencv_camera": (
        lambda x: [torch.from_numpy(a) for a in camera_export.opencv_camera(x.cal.camera)], {"float_dtype": F64}),
    "camera_export.opencv_distortion": (
        lambda x: torch.from_numpy(camera_export.opencv_distortion(_bent(x))), {"float_dtype": F64}),
    "camera_export.pinhole_keys": (
        lambda x: torch.tensor(np.hstack([[v] if isinstance(v, float) else v for v in camera_export.pinhole_keys(
            _bent(x)[0]).values()])), {"float_dtype": F64}),
    "camera_model.calibrate_camera_model": (
        lambda x: camera_model.calibrate_camera_model(
            _FixedSearch(x), frame_search.View(x.images, x.segments, x.mask),
            Priors(principal_point=(150.0, 110.0), k1=-0.05, focal=300.0)).result, {}),
    "camera_model.joint_options": (
        lambda x: (lambda o: torch.tensor([*o.priors["principal_point"], o.priors["k1"], *o.point_std], dtype=F64))(
            camera_model.joint_options([camera_model.option_evidence(_with_options(x), ESTIMATES)],
                                       pipeline_room.ParserConfig(), x.height, x.width)), {"float_dtype": F64}),
    "camera_model.option_evidence": (lambda x: camera_model.option_evidence(_with_options(x), ESTIMATES), {}),
    "camera_model.with_shared_options": (
        lambda x: camera_model.with_shared_options(x.cal, camera_model.SharedOptions({}, (2.0, 3.0))), {}),
    "camera_model.moved_calibration": (
        lambda x: camera_model.moved_calibration(x.cal, 0.01 * x.cal.principal_point), {}),
    "candidates.sample_horizontal_pair_frames": (
        lambda x: candidates.sample_horizontal_pair_frames(x.trace.horizontal_vps, x.trace.horizontal_ok, 32,
                                                           generator=x.generators), {"tol": False}),
    "candidates.horizontal_line_mask": (
        lambda x: candidates.horizontal_line_mask(x.pseudo, x.mask, x.trace.zenith_estimate), {}),
    "candidates.nearest_vertical_endpoint": (
        lambda x: candidates.nearest_vertical_endpoint(x.pseudo, x.trace.horizontal & x.mask), {}),
    "candidates.sample_frames": (
        lambda x: candidates.sample_frames(x.trace.zenith_candidates, x.trace.zenith_weights, x.trace.horizontal_vps,
                                           x.trace.horizontal_ok, 32, generator=x.generators), {"tol": False}),
    "candidates.sample_horizontal_vps": (
        lambda x: candidates.sample_horizontal_vps(x.lines, x.lengths, x.trace.horizontal, x.trace.right, 32,
                                                   x.generators), {"tol": False}),
    "candidates.sample_candidate_frames": (
        lambda x: candidates.sample_candidate_frames(x.trace.zenith_candidates, x.trace.zenith_weights,
                                                     x.trace.horizontal_vps, x.trace.horizontal_ok, 32, 16,
                                                     generator=x.generators), {"tol": False}),
    "candidates.sample_pairs": (lambda x: candidates.sample_pairs(x.lengths, 16, x.generators), {}),
    "candidates.sample_zenith_candidates": (
        lambda x: candidates.sample_zenith_candidates(x.lines, x.lengths, x.mask, 16, 16, generator=x.generators),
        {"tol": False}),
    "candidates.split_by_pseudo_horizon": (
        lambda x: candidates.split_by_pseudo_horizon(x.lines, x.trace.zenith_estimate), {}),
    "constants.cached": (
        lambda x: constants.cached(("dtype test", x.dtype, x.device), lambda: torch.ones(2).to(x.cal.K)), {}),
    "constants.numbers_like": (lambda x: constants.numbers_like(x.cal.K, 1.5, -2.0), {}),
    "constants.rows_like": (lambda x: constants.rows_like(x.cal.K, [[1.0, 2.0]], [[3.0]]), {}),
    "distortion.chained_pairs": (
        lambda x: distortion.chained_pairs(x.pseudo, x.mask, DistortionSettings()), {"tol": False}),
    "distortion.distortion_costs": (
        lambda x: distortion.distortion_costs(x.pseudo, *distortion.chained_pairs(x.pseudo, x.mask,
                                              DistortionSettings())[:2], torch.tensor([-0.1, 0.0, 0.1]).to(x.cal.K)),
        {"tol": False}),
    "distortion.estimate_distortion": (
        lambda x: distortion.estimate_distortion(x.segments, x.mask, x.cal.principal_point, x.height, x.width),
        {"tol": False}),
    "evidence.apply_evidence": (
        lambda x: evidence.apply_evidence(_evidence_net(x), x.images, x.segments, x.mask), {"tol": False}),
    "gravity.allowed_ups": (lambda x: gravity.allowed_ups(x.ups, x.priors), {}),
    "gravity.frame_agreement": (lambda x: gravity.frame_agreement(_frames_r(x), x.priors), {}),
    "gravity.gravity_frame_scores": (
        lambda x: gravity.gravity_frame_scores(x.trace.manhattan, _frames_r(x), x.priors), {}),
    "gravity.gravity_zenith_weights": (
        lambda x: gravity.gravity_zenith_weights(x.trace.zenith_weights, x.trace.zenith_candidates, x.priors), {}),
    "gravity.prior_up": (lambda x: gravity.prior_up(x.priors, x.cal.K), {}),
    "gravity.zenith_agreement": (lambda x: gravity.zenith_agreement(x.trace.zenith_candidates, x.priors), {}),
    "horizon.choose_horizon": (lambda x: horizon.choose_horizon(x.cal, _found(x)), {"tol": False}),
    "horizon.refine_horizon": (lambda x: horizon.refine_horizon(x.cal, x.segments, x.mask), {"tol": False}),
    "horizon.search_horizon": (_found, {"tol": False}),
    "horizon_support.horizon_support": (
        lambda x: horizon_support.horizon_support(x.ups, x.segments, x.mask, x.cal.K), {"tol": False}),
    "horizon_support.refine_up": (
        lambda x: horizon_support.refine_up(x.cal.up, x.segments, x.mask, x.cal.K), {"tol": 1e-2}),
    "horizon_support.refine_up_on_camera": (
        lambda x: horizon_support.refine_up_on_camera(x.cal.up, x.cam, x.lengths, x.mask, 2.0, 2), {"tol": 1e-2}),
    "horizon_support.support_on_camera": (
        lambda x: horizon_support.support_on_camera(x.ups, x.cam, x.lengths, line_kernel.total_length(x.lengths), 4,
                                                    1.0, 360, 3.0, None), {"tol": False}),
    "horizon_support.up_from_pitch_roll": (
        lambda x: horizon_support.up_from_pitch_roll(x.cal.pitch, x.cal.roll), {}),
    "line_kernel.camera_points": (lambda x: line_kernel.camera_points(x.segments, x.cal.K), {}),
    "line_kernel.camera_segments": (lambda x: line_kernel.camera_segments(x.segments, x.cal.K), {}),
    "line_kernel.camera_segments_at_scales": (
        lambda x: line_kernel.camera_segments_at_scales(x.segments, x.cal.K, [1.0, 0.9, 1.1]), {}),
    "line_kernel.camera_terms": (
        lambda x: line_kernel.camera_terms(*line_kernel.camera_points(x.segments, x.cal.K)), {}),
    "line_kernel.closeness_kernel": (
        lambda x: line_kernel.closeness_kernel(x.cam, x.cal.R.transpose(1, 2)[:, None], 1.5, x.mask), {"tol": 1e-2}),
    "line_kernel.near_direction": (lambda x: line_kernel.near_direction(x.cam, x.cal.up, 0.01), {}),
    "line_kernel.scale_constants": (lambda x: line_kernel.scale_constants([0.9, 1.0, 1.1], x.cal.K), {}),
    "line_kernel.scaled_camera_segments": (
        lambda x: line_kernel.scaled_camera_segments(x.cam, *line_kernel.scale_constants([0.9, 1.1], x.cal.K)[1:]),
        {}),
    "line_kernel.scaled_focal": (lambda x: line_kernel.scaled_focal(x.cal.K, torch.tensor([0.9, 1.1]).to(x.cal.K)), {}),
    "line_kernel.squared_sines": (lambda x: line_kernel.squared_sines(x.cam, x.cal.R.transpose(1, 2)), {}),
    "line_kernel.total_length": (lambda x: line_kernel.total_length(x.lengths), {}),
    "parser.checked_segments": (lambda x: parser.checked_segments(x.segments, x.mask, 2), {}),
    "frame_search.pseudo_lines": (lambda x: frame_search.pseudo_lines(x.segments, x.mask, x.height, x.width), {}),
    "polish.polish_frame": (lambda x: polish.polish_frame(x.cal.K, x.cal.R, x.segments, x.mask), {"tol": False}),
    "polish.refit_rotation": (
        lambda x: polish.refit_rotation(x.cam, x.lengths, x.mask, x.cal.R, 1.5, 2), {"tol": 1e-2}),
    "principal_point.estimate_principal_point": (
        lambda x: principal_point.estimate_principal_point(x.cal.K, x.cal.R, x.segments, x.mask, 20.0),
        {"tol": False}),
    "principal_point.orthocentre": (lambda x: principal_point.orthocentre(x.cal.vps), {}),
    "runner.calibrate_input": (
        lambda x: runner.calibrate_input(x.images[:1], _one_input(x, 0), _run(x)), {"tol": False}),
    "runner.calibrate_list": (lambda x: runner.calibrate_list(list(x.images), _run(x)), {"tol": False}),
    "runner.read_input": (lambda x: runner.read_input(x.images, _run(x)).batch, {}),
    "runner.with_orientation": (lambda x: runner.with_orientation(x.cal[0], 6), {}),
    "segments.detect_segments": (lambda x: segments_stage.detect_segments(x.images[:, :, :96, :128]), {"tol": False}),
    "segments.longest_segments": (lambda x: torch.from_numpy(segments_stage.longest_segments(
        x.segments[0].double().cpu().numpy(), 10.0, 5)).to(x.segments), {}),
    "segments.pad_segments": (
        lambda x: segments_stage.pad_segments([x.segments[0, :3], x.segments[1, :5]], like=x.images), {}),
    "shared_camera.calibrate_shared": (
        lambda x: shared_camera.calibrate_shared(list(_photos().to(x.device, x.dtype)), _run(x)._replace(
            priors=Priors())), {"tol": False}),
    "shared_camera.focal_grid": (
        lambda x: shared_camera.focal_grid(x.height, x.width, SharedSettings(), SamplingSettings()),
        {"float_dtype": F64}),
    "shared_camera.focal_support": (
        lambda x: shared_camera.focal_support(x.cal.K, x.cal.R, x.segments, x.mask,
                                              torch.linspace(200.0, 400.0, 5).to(x.cal.K)),
        {"float_dtype": F64, "tol": False}),
    "shared_camera.joint_focal": (
        lambda x: torch.tensor([float(v) for v in _shared_focal(x)[:2]], dtype=F64),
        {"float_dtype": F64, "tol": False}),
    "distortion.joint_distortion": (lambda x: torch.tensor([distortion.joint_distortion(torch.tensor([-0.1, -0.12]).to(
        x.cal.K))], dtype=F64), {"float_dtype": F64}),
    "principal_point.joint_principal_point": (
        lambda x: torch.tensor(principal_point.joint_principal_point(x.cal.principal_point, torch.ones_like(
            x.cal.principal_point), x.cal.principal_point[0], 10.0), dtype=F64), {"float_dtype": F64}),
    "shared_camera.nearest_rotation": (
        lambda x: shared_camera.nearest_rotation(x.cal.R + 0.01 * torch.ones_like(x.cal.R)), {}),
    "shared_camera.with_shared_focal": (
        lambda x: shared_camera.with_shared_focal(x.cal, _shared_focal(x)), {"tol": False}),
    "trust.attach_trust": (
        lambda x: trust.attach_trust(x.cal, x.trace.final_frames, x.trace.final_scores, x.segments, x.mask),
        {"tol": False}),
    "trust.confidence_inputs": (
        lambda x: trust.confidence_inputs(trust_features.trust_features(
            x.cal, x.trace.final_frames, x.trace.final_scores, x.segments, x.mask)), {"tol": False}),
    "trust.principal_point_terms": (
        lambda x: trust.principal_point_terms(0.02, x.cal.focal, x.height, x.cal.pitch), {}),
    "trust_features.line_residual": (lambda x: trust_features.line_residual(x.cal.vps, x.segments, x.mask), {}),
    "trust_features.support_rival": (
        lambda x: trust_features.support_rival(_found(x), x.cal.horizon, x.height, x.width), {"tol": False}),
    "trust_features.trust_features": (
        lambda x: trust_features.trust_features(x.cal, x.trace.final_frames, x.trace.final_scores, x.segments,
                                                x.mask), {"tol": False}),
    "upright_check.apply_upright": (
        lambda x: upright_check.apply_upright(x.cal, torch.tensor([[0.7, 0.1, 0.1, 0.05, 0.05]] * 2).to(x.cal.K),
                                              0.5, True), {}),
    "upright_check.read_beside": (  # the orientation network reads a float32 thumbnail, whatever the image's dtype
        lambda x: upright_check.read_beside(_upright_net(x), x.images, 0.5)(),
        {"tol": 1e-4, "float_dtype": torch.float32}),
    "upright_check.fuse_line_reading": (
        lambda x: upright_check.fuse_line_reading(_lines_net(x), torch.tensor([[0.5, 0.2, 0.1, 0.1, 0.1]] * 2).to(
            x.cal.K), torch.log(torch.tensor([[0.1, 0.6, 0.2, 0.1]] * 2)).to(x.cal.K)), {}),
    "upright_check.read_lines_beside": (  # the reader runs in its own dtype, float32, whatever the segments'
        lambda x: upright_check.read_lines_beside(_lines_net(x), x.segments, x.mask, (x.height, x.width))(),
        {"tol": 1e-4, "float_dtype": torch.float32}),
    "upright_check.with_prior": (
        lambda x: upright_check.with_prior(torch.tensor([[0.4, 0.3, 0.1, 0.1, 0.1]] * 2).to(x.cal.K), 0.75), {}),
    "upright_check.turned_answer": (
        lambda x: upright_check.turned_answer(x.cal, torch.tensor([1, 2], device=x.device),
                                              torch.tensor([True, False], device=x.device)), {}),
    "upright_check.upright_probabilities": (
        lambda x: upright_check.upright_probabilities(_upright_net(x), x.images),
        {"tol": 1e-4, "float_dtype": torch.float32}),
    "upright_check.weigh_by_pitch": (
        lambda x: upright_check.weigh_by_pitch(torch.tensor([[0.7, 0.1, 0.1, 0.05, 0.05]] * 2).to(x.cal.K),
                                               x.cal.pitch, 10.0), {}),
}  # fmt: skip

#: public functions with no tensor of a chosen dtype to test: their inputs and outputs are settings or plain values
NOT_TENSORS = {
    "camera_model.estimates": "reads the priors",
    "camera_model.option_errors": "compares an estimate's plain numbers with the truth (the evaluation's)",
    "camera_model.option_values": "one photo's camera options as plain numbers (the evaluation's)",
    "result.lens_from_dict": "reads a number of a calibration's dict",
    "camera_model.tied_to_pixels": "reads the priors",
    "focal_prior.check_focal_on_image": "checks numbers of a focal-length prior",
    "focal_prior.checked_focal": "checks a number",
    "focal_prior.checked_focal_35mm": "checks a number",
    "focal_prior.checked_fov_v": "checks a number",
    "focal_prior.focal_pixels_of": "converts numbers",
    "focal_prior.positive_number": "checks a number",
    "priors.checked_priors": "checks a mapping of priors",
    "runner.file_priors": "reads a file's EXIF focal length into the priors",
    "runner.item_run": "picks a list item's priors",
    "runner.naming_item": "the words of an error",
    "runner.on_device": "moves a parser's networks (runner.calibrate_input runs it on every device)",
    "runner.pixels": "an 8-bit numpy image to float32 (read_input's numpy path)",
    "shared_camera.shared_camera": "the first pass of calibrate_shared over files (ngp predict --same-camera)",
    "weight_sets.check_weights": "loads networks by name",
    "weight_sets.checked_config": "checks a ParserConfig or dict, no tensors",
    "weight_sets.network_roles": "names networks",
    "weight_sets.weight_set_config": "the settings of a weight set",
    "priors.checked_seed": "checks an int seed",
    "segments.detect_segments_gray": "OpenCV's LSD on a uint8 numpy image; detect_segments is its tensor form",
    "segments.line_workers": "a context manager for LSD's threads",
    "segments.longest_segments": "selects rows of a numpy array of segments; detect_segments is its tensor form",
    "segments.strip_threads": "an int: how many threads the strips use",
    "settings.check_settings": "checks settings dataclasses",
    "shared_camera.not_shared_folders": "the words of a warning",
    "shared_camera.not_shared_message": "the words of a warning",
    "settings.locate_setting": "finds a setting by name",
    "settings.setting_fields": "lists settings' fields",
}


def test_every_public_function_is_covered():
    functions = set(public_functions(pipeline_room))
    assert functions == set(CASES) | set(NOT_TENSORS), (
        f"untested: {sorted(functions - set(CASES) - set(NOT_TENSORS))}; "
        f"gone: {sorted((set(CASES) | set(NOT_TENSORS)) - functions)}"
    )


@pytest.mark.parametrize("name", sorted(CASES))
def test_pipeline_function_keeps_device_and_dtype(name, device, dtype):
    call, options = CASES[name]
    with torch.no_grad():
        out = call(inputs(device.type, dtype))
        reference = call(inputs("cpu", F64))
    check_output(out, reference, device.type, dtype, **options)


# --- gradients where the docs promise them (float64, small inputs) ---


def test_gradcheck_camera_space_segments_and_their_kernel():
    x = inputs("cpu", F64)
    segments = x.segments[:, :6].clone().requires_grad_()
    R = x.cal.R.clone()

    def kernel(seg, K):
        cam = line_kernel.camera_segments(seg, K)
        return line_kernel.squared_sines(cam, R.transpose(1, 2)), line_kernel.closeness_kernel(
            cam, R.transpose(1, 2)[:, None], 20.0, None)

    assert gradcheck(kernel, (segments, x.cal.K.clone().requires_grad_()))


def test_gradcheck_calibration_of_a_camera_and_its_moves():
    x = inputs("cpu", F64)

    def fields(K, R, offset):
        cal = camera_model.moved_calibration(
            answer.calibration_from_camera(K, R, x.cal.score, x.cal.valid, x.height, x.width), offset)
        return cal.horizon, cal.zenith, cal.vps, cal.fov_v, cal.pitch, cal.roll

    offset = torch.tensor([[2.0, -3.0], [0.5, 1.0]], dtype=F64, requires_grad=True)
    assert gradcheck(fields, (x.cal.K.clone().requires_grad_(), x.cal.R.clone().requires_grad_(), offset))


def test_gradcheck_small_pipeline_maps():
    x = inputs("cpu", F64)
    pitch, roll = x.cal.pitch.clone().requires_grad_(), x.cal.roll.clone().requires_grad_()
    assert gradcheck(horizon_support.up_from_pitch_roll, (pitch, roll))
    focal = x.cal.focal.clone().requires_grad_()
    lam = torch.tensor([-0.1, 0.05], dtype=F64, requires_grad=True)
    assert gradcheck(lambda k, f: coefficient_to_pseudo(k, f, x.height, x.width), (lam, focal))
    assert gradcheck(lambda u, f: coefficient_from_pseudo(u, f, x.height, x.width), (lam, focal))
    assert gradcheck(principal_point.orthocentre, (x.cal.vps.clone().requires_grad_(),))
    probs = torch.tensor([[0.7, 0.1, 0.1, 0.05, 0.05], [0.2, 0.5, 0.1, 0.1, 0.1]], dtype=F64, requires_grad=True)
    assert gradcheck(lambda p: upright_check.weigh_by_pitch(p, x.cal.pitch, 10.0), (probs,))


def test_gradients_reach_the_frames_through_the_top_k_average():
    x = inputs("cpu", F64)
    frames = x.trace.final_frames
    zenith = frames.zenith.clone().requires_grad_()
    focal = frames.focal.clone().requires_grad_()
    scores = x.trace.final_scores.clone().requires_grad_()
    moved = FrameCandidates(zenith, frames.horizontal, focal, frames.R, frames.vps, frames.valid)
    cal, _ = answer.topk_calibration(moved, scores, x.height, x.width, ScoringSettings())
    (cal.horizon.sum() + cal.focal.sum()).backward()
    for t in (zenith, focal, scores):
        assert t.grad is not None and bool(torch.isfinite(t.grad).all()) and bool(t.grad.abs().sum() > 0)


# --- a batch gives each image what it gets alone ---


@pytest.mark.parametrize("name", ["camera_model.moved_calibration", "line_kernel.camera_points",
                                  "trust_features.line_residual", "frame_search.pseudo_lines", "polish.polish_frame",
                                  "horizon.search_horizon", "principal_point.orthocentre"])  # fmt: skip
def test_batch_equals_alone(name):
    x = inputs("cpu", F64)
    batch = tensors(CASES[name][0](x))
    for i in range(2):
        alone = tensors(CASES[name][0](_one(x, i)))
        for b, a in zip(batch, alone, strict=True):
            torch.testing.assert_close(b[i : i + 1], a, msg=f"{name}: image {i}")


def _one(x, i):
    """The inputs of image ``i`` alone, as a batch of one (with the batch's padding)."""
    out = type(x)(**vars(x))
    out.segments, out.mask, out.lengths = x.segments[i : i + 1], x.mask[i : i + 1], x.lengths[i : i + 1]
    out.cal = x.cal.apply(lambda t: t[i : i + 1])
    out.cam = line_kernel.camera_segments(out.segments, out.cal.K)
    return out
