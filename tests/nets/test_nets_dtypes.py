"""Every public function and network of nets/ in float32 and float64 on every available device: outputs on the
input's device, floating outputs in its dtype and finite, and close to the float64 CPU values; gradcheck in float64
where the docs promise gradients (FSNet with respect to every input); a batch gives each image what it gets alone."""

from __future__ import annotations

import pytest
import torch
from torch.autograd import gradcheck

import ngp_kornia.nets as nets_room
from ngp_kornia.nets import fsnet_inputs, line_evidence, line_features, resnet, upright, upright_lines, zsnet
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.line_evidence import LineEvidenceNet
from ngp_kornia.nets.resnet import ResNet
from ngp_kornia.nets.upright import UprightNet
from ngp_kornia.nets.upright_lines import UprightLinesNet
from ngp_kornia.nets.zsnet import ZSNet
from tests.rooms import check_output, inputs, public_functions, tensors

F64 = torch.float64


def _net(cls, x, **kw):
    torch.manual_seed(0)
    return cls(**kw).to(x.device, x.dtype).eval()


def _fsnet(x):
    return _net(FSNet, x, variant="shared", widths=(8, 16), depths=(1, 1), head_width=8, input_size=64)


def _image_inputs(x):
    return fsnet_inputs.fsnet_image_inputs(x.images, x.segments, x.mask, size=64, pool=8)


def _frames(x):
    return x.trace.final_frames


#: module.function (or a network's forward) -> (the call on the inputs, options for check_output)
CASES = {
    "fsnet_inputs.area_resize": (lambda x: fsnet_inputs.area_resize(x.images, (60, 80)), {"tol": 1e-6}),
    "fsnet_inputs.canonical_frame_vps": (lambda x: fsnet_inputs.canonical_frame_vps(_frames(x)), {}),
    "fsnet_inputs.draw_maps": (
        lambda x: fsnet_inputs.draw_maps(_image_inputs(x), x.mask, fsnet_inputs.frame_closeness(
            x.lines, fsnet_inputs.canonical_frame_vps(_frames(x))), 4), {}),
    "fsnet_inputs.frame_closeness": (
        lambda x: fsnet_inputs.frame_closeness(x.lines, fsnet_inputs.canonical_frame_vps(_frames(x))), {}),
    "fsnet_inputs.frame_scores": (
        lambda x: fsnet_inputs.frame_scores(torch.sigmoid(x.trace.final_scores), x.trace.final_scores,
                                            _frames(x).valid), {}),
    "fsnet_inputs.frame_support": (
        lambda x: fsnet_inputs.frame_support(x.lines, x.lengths, x.mask, fsnet_inputs.canonical_frame_vps(_frames(x))),
        {}),
    "fsnet_inputs.fsnet_frame_inputs": (
        lambda x: fsnet_inputs.fsnet_frame_inputs(_image_inputs(x), x.segments, x.mask, _frames(x)), {}),
    "fsnet_inputs.fsnet_image_inputs": (_image_inputs, {"tol": 1e-6}),
    "fsnet_inputs.fsnet_inputs": (
        lambda x: fsnet_inputs.fsnet_inputs(x.images, x.segments, x.mask, _frames(x), size=64), {}),
    "fsnet_inputs.fsnet_line_inputs": (
        lambda x: fsnet_inputs.fsnet_line_inputs(x.segments, x.mask, (x.height, x.width), size=64, pool=8), {}),
    "fsnet_inputs.with_images": (
        lambda x: fsnet_inputs.with_images(fsnet_inputs.fsnet_line_inputs(x.segments, x.mask, (x.height, x.width),
                                                                          size=64), x.images), {"tol": 1e-6}),
    "line_evidence.structure_weights": (
        lambda x: line_evidence.structure_weights(x.lengths / 100.0 - 1.0, x.mask), {}),
    "line_features.check_inputs": (
        lambda x: (line_features.check_inputs(x.images, x.segments, x.mask), x.images)[1], {}),
    "line_features.context_features": (
        lambda x: line_features.context_features(x.segments, x.mask, x.height, x.width), {"tol": 1e-2}),
    "line_features.geometry_features": (
        lambda x: line_features.geometry_features(x.segments, x.height, x.width), {}),
    "line_features.segment_features": (
        lambda x: line_features.segment_features(x.images, x.segments, x.mask), {"tol": 1e-2}),
    "line_features.sphere_directions": (  # a constant grid, float32 (the vote's bins), whatever the inputs
        lambda x: line_features.sphere_directions(50), {"float_dtype": torch.float32}),
    "line_features.to_working_resolution": (
        lambda x: line_features.to_working_resolution(x.segments, x.height, x.width)[0], {}),
    "resnet.make_norm": (lambda x: resnet.make_norm("batch", 3).to(x.device, x.dtype).eval()(x.images), {}),
    "upright.thumbnail": (  # the orientation network's input: float32 whatever the images' dtype
        lambda x: upright.thumbnail(x.images, 32), {"float_dtype": torch.float32, "tol": 1e-6}),
    "upright_lines.line_turn_features": (
        lambda x: upright_lines.line_turn_features(x.segments, x.mask, x.height, x.width), {}),
    "upright_lines.mirror_segments": (lambda x: upright_lines.mirror_segments(x.segments, x.width), {}),
    "upright_lines.turn_segments": (lambda x: upright_lines.turn_segments(x.segments, x.height, x.width, 3)[0], {}),
    "zsnet.canonical_homogeneous": (lambda x: zsnet.canonical_homogeneous(x.trace.zenith_candidates, 1), {}),
    "zsnet.zenith_estimate": (
        lambda x: zsnet.zenith_estimate(x.trace.zenith_candidates, x.trace.zenith_weights), {}),
    "zsnet.zenith_weights_from_scores": (
        lambda x: zsnet.zenith_weights_from_scores(x.trace.zenith_weights * 5, x.trace.zenith_ok), {}),
    # the networks
    "FSNet.forward": (lambda x: _fsnet(x)(*fsnet_inputs.fsnet_inputs(
        x.images, x.segments, x.mask, _frames(x), size=64, pool=8)[:4]), {"tol": 1e-3}),
    "ZSNet.forward": (
        lambda x: _net(ZSNet, x, width=8)(x.lines, x.mask, x.trace.zenith_candidates), {"tol": 1e-3}),
    "LineEvidenceNet.forward": (
        lambda x: _net(LineEvidenceNet, x, width=8, context=4)(x.images, x.segments, x.mask), {"tol": 1e-2}),
    "UprightNet.forward": (
        lambda x: _net(UprightNet, x, size=32, width=4)(upright.thumbnail(x.images, 32).to(x.dtype)), {"tol": 1e-3}),
    "UprightLinesNet.forward": (
        lambda x: _net(UprightLinesNet, x, width=8, members=2)(x.segments, x.mask, x.height, x.width), {"tol": 1e-3}),
    "ResNet.forward": (
        lambda x: _net(ResNet, x, widths=(4, 8), depths=(1, 1))(x.images[:, :, :64, :64]), {"tol": 1e-3}),
}  # fmt: skip

#: public functions with no tensor of a chosen dtype: they read, write or name the networks' weight files
NOT_TENSORS = {
    "weights.build_network": "builds a network from its stored settings",
    "weights.load_network": "reads a weights file",
    "weights.load_tensors_safely": "reads a weights file",
    "weights.network_name": "a name",
    "weights.save_network": "writes a weights file",
    "weights.shipped_weights": "a path",
}


def test_every_public_function_is_covered():
    functions = set(public_functions(nets_room))
    covered = {name for name in CASES if "." in name and not name.split(".")[0][0].isupper()}
    assert functions == covered | set(NOT_TENSORS), (
        f"untested: {sorted(functions - covered - set(NOT_TENSORS))}; "
        f"gone: {sorted((covered | set(NOT_TENSORS)) - functions)}"
    )


@pytest.mark.parametrize("name", sorted(CASES))
def test_nets_function_keeps_device_and_dtype(name, device, dtype):
    call, options = CASES[name]
    with torch.no_grad():
        out = call(inputs(device.type, dtype))
        reference = call(inputs("cpu", F64))
    check_output(out, reference, device.type, dtype, **options)


def test_gradcheck_fsnet_with_respect_to_every_input():
    torch.manual_seed(0)
    net = FSNet("shared", widths=(4, 8), depths=(1, 1), head_width=4, input_size=16).double().eval()
    g = torch.Generator().manual_seed(0)
    images = torch.rand(1, 3, 16, 16, generator=g, dtype=F64)
    line_map = (torch.rand(1, 1, 16, 16, generator=g, dtype=F64) > 0.7).double()
    closeness = torch.rand(1, 2, 3, 2, 2, generator=g, dtype=F64)  # pooled to the trunk's 2 x 2 cells
    params = torch.randn(1, 2, fsnet_inputs.NUM_PARAMS, generator=g, dtype=F64)
    args = tuple(t.requires_grad_() for t in (images, line_map, closeness, params))
    assert gradcheck(net, args, atol=1e-6)


def test_gradcheck_the_differentiable_inputs_and_weights():
    x = inputs("cpu", F64)
    g = torch.Generator().manual_seed(1)  # random lines and VPs: no line through a VP, where |cos| has its kink
    lines = torch.randn(2, 8, 3, generator=g, dtype=F64, requires_grad=True)
    vps = torch.randn(2, 3, 3, 3, generator=g, dtype=F64, requires_grad=True)
    assert gradcheck(lambda a, b: fsnet_inputs.frame_closeness(a, b, None), (lines, vps))
    near = (x.lines[:, :8] + 0.01 * torch.randn(2, 8, 3, generator=g, dtype=F64)).requires_grad_()
    assert gradcheck(lambda a: fsnet_inputs.frame_closeness(a, vps.detach(), 60.0), (near,))
    logits = torch.randn(2, 5, dtype=F64, requires_grad=True)
    assert gradcheck(lambda t: line_evidence.structure_weights(t, x.mask[:, :5]), (logits,))
    candidates = x.trace.zenith_candidates[:, :6].clone().requires_grad_()
    weights = x.trace.zenith_weights[:, :6].clone().requires_grad_()
    assert gradcheck(zsnet.zenith_estimate, (candidates, weights))


def test_gradients_reach_the_images_through_the_area_resize():
    x = inputs("cpu", F64)
    images = x.images.clone().requires_grad_()
    fsnet_inputs.area_resize(images, (60, 80)).sum().backward()
    assert images.grad is not None and bool(images.grad.abs().sum() > 0)


@pytest.mark.parametrize("name", ["fsnet_inputs.frame_support", "line_features.segment_features",
                                  "line_features.context_features", "LineEvidenceNet.forward", "ZSNet.forward"])
def test_batch_equals_alone(name):
    x = inputs("cpu", F64)
    with torch.no_grad():
        batch = tensors(CASES[name][0](x))
        for i in range(2):
            alone = tensors(CASES[name][0](_one(x, i)))
            for b, a in zip(batch, alone, strict=True):
                torch.testing.assert_close(b[i : i + 1], a, msg=f"{name}: image {i}")


def _one(x, i):
    """The inputs of image ``i`` alone, as a batch of one (with the batch's padding)."""
    out = type(x)(**vars(x))
    for name in ("images", "segments", "mask", "lengths", "lines", "pseudo"):
        setattr(out, name, getattr(x, name)[i : i + 1])
    trace = type(x.trace)(**vars(x.trace))
    trace.zenith_candidates = x.trace.zenith_candidates[i : i + 1]
    trace.final_frames = type(x.trace.final_frames)(*(t[i : i + 1] for t in vars(x.trace.final_frames).values()))
    out.trace = trace
    return out
