"""FSNet and its ResNet backbone: shapes, candidate-order equivariance, the shared trunk running once, the ablations'
input channels, the input maps of a synthetic scene, gradients to the image, settings."""

import math

import pytest
import torch

from ngp_kornia.geometry import rasterize_segments, rotation_from_angles
from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.nets.fsnet import FSNet
from ngp_kornia.nets.fsnet_inputs import NUM_PARAMS, NUM_SUPPORT, SUPPORT_ANGLES, canonical_frame_vps, fsnet_inputs
from ngp_kornia.nets.resnet import LAYOUTS, ResNet

TINY = {"widths": (8, 16), "depths": (1, 1), "head_width": 8}


def tiny(variant, **kw):
    torch.manual_seed(0)
    return FSNet(variant, **{**TINY, **kw})


def random_inputs(b=2, f=5, size=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    lmap = (torch.rand(b, 1, size, size, generator=g) > 0.8).float()
    return (
        torch.rand(b, 3, size, size, generator=g),
        lmap,
        torch.rand(b, f, 3, size, size, generator=g) * lmap[:, None],
        torch.randn(b, f, NUM_PARAMS, generator=g),
    )


def frames(R, focal):
    """FrameCandidates holding only what FSNet's inputs read (R and focal)."""
    return FrameCandidates(None, None, focal, R, None, focal > 0)


@pytest.mark.parametrize("variant", ["faithful", "shared"])
@pytest.mark.parametrize(("b", "f"), [(1, 1), (2, 5), (3, 0)])
def test_one_logit_per_candidate(variant, b, f):
    out = tiny(variant).eval()(*random_inputs(b, f))
    assert out.shape == (b, f)
    assert torch.isfinite(out).all()


@pytest.mark.parametrize("variant", ["faithful", "shared"])
def test_permuting_candidates_permutes_scores_and_chunks_do_not_matter(variant):
    net = tiny(variant, chunk_size=4).eval()  # chunks of 2 candidates for b = 2: permutations cross chunks
    images, lmap, close, params = random_inputs(2, 7)
    perm = torch.randperm(7, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out = net(images, lmap, close, params)
        out_perm = net(images, lmap, close[:, perm], params[:, perm])
        net.chunk_size = 64
        out_one_chunk = net(images, lmap, close, params)
    assert torch.allclose(out_perm, out[:, perm], atol=1e-5)
    assert torch.allclose(out_one_chunk, out, atol=1e-5)
    assert not torch.allclose(out[:, 0], out[:, 1])  # the candidates do matter


@pytest.mark.parametrize(("variant", "calls"), [("shared", 1), ("faithful", 5)])
def test_shared_trunk_runs_once_per_batch(variant, calls):
    net = tiny(variant, chunk_size=4).eval()  # 2 images: 2 candidates per chunk, 5 chunks for 9 candidates
    count = []
    net.backbone.register_forward_hook(lambda *_: count.append(1))
    with torch.no_grad():
        net(*random_inputs(2, 9))
    assert len(count) == calls


@pytest.mark.parametrize(
    ("use_image", "use_maps", "faithful_ch", "shared_ch"),
    [(True, True, 17, 4), (False, True, 14, 1), (True, False, 13, 3), (False, False, 10, 0)],
)
def test_ablations_drop_input_channels(use_image, use_maps, faithful_ch, shared_ch):
    images, lmap, close, params = random_inputs(1, 3)
    other_images, other_lmap, other_close, _ = random_inputs(1, 3, seed=5)
    for variant, channels in (("faithful", faithful_ch), ("shared", shared_ch)):
        net = tiny(variant, use_image=use_image, use_maps=use_maps).eval()
        assert net.in_channels == channels
        if channels:
            assert net.backbone.stem[0].in_channels == channels
        else:
            assert net.backbone is None
        with torch.no_grad():
            out = net(images, lmap, close, params)
            new_image = net(other_images, lmap, close, params)
            new_maps = net(images, other_lmap, other_close, params)
        assert torch.allclose(new_image, out) == (not use_image)
        assert torch.allclose(new_maps, out) == (not use_maps)


def test_fsnet_inputs_draw_segments_with_their_closeness():
    H, W, size = 100, 200, 64
    segments = torch.tensor(
        [
            [[50.0, 10.0], [50.0, 90.0]],  # vertical: through the VP (0, 1, 0)
            [[20.0, 30.0], [180.0, 30.0]],  # horizontal: through the VP (1, 0, 0)
            [[100.0, 40.0], [160.0, 95.0]],  # diagonal, masked out in both images
        ]
    ).expand(2, 3, 2, 2)
    mask = torch.tensor([[True, True, False], [True, False, False]])
    yaw90 = torch.tensor([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # same frame, axes relabelled
    R = torch.stack([torch.eye(3), yaw90]).expand(2, 2, 3, 3)
    fr = frames(R, torch.tensor([[1.0, 2.0], [1.0, 0.0]]))  # frame (1, 1) invalid: focal 0
    images = torch.rand(2, 3, H, W)
    x = fsnet_inputs(images, segments, mask, fr, size=size, kernel_angle=None)

    assert x.images.shape == (2, 3, size, size) and x.closeness.shape == (2, 2, 3, size, size)
    col = round(50.5 * size / W - 0.5)  # pixel centres map to pixel centres
    row = round(30.5 * size / H - 0.5)
    c = -0.495  # x of the vertical segment in the pseudo camera: (50 - 99.5) / 100
    expect_x = 1 - 1 / math.sqrt(1 + c**2)  # Eq. 14 of the line (1, 0, -c) and the VP (1, 0, 0)
    expect_z = 1 - abs(c) / math.sqrt(1 + c**2)
    assert (x.line_map[:, 0, 10:55, col] == 1).all()
    vertical = x.closeness[0, 0, :, 25:55, col]  # below the crossing with the horizontal line (which keeps the max)
    assert torch.allclose(vertical[1], torch.ones(30))
    assert torch.allclose(vertical[0], torch.full((30,), expect_x), atol=1e-5)
    assert torch.allclose(vertical[2], torch.full((30,), expect_z), atol=1e-5)
    assert torch.allclose(x.closeness[0, 0, 0, row, 10:55], torch.ones(45))  # horizontal line: A_x = 1
    # the masked diagonal is never drawn; image 1 has only the vertical segment
    assert x.line_map[0].sum() == (x.line_map[0, 0, :, col] > 0).sum() + (x.line_map[0, 0, row] > 0).sum() - 1
    assert x.line_map[1].sum() == (x.line_map[1, 0, :, col] > 0).sum()
    assert (x.closeness[1] <= x.line_map[1]).all()
    # the relabelled frame gives the same VPs, so the same maps at another focal length (VPs at infinity)
    assert torch.allclose(x.closeness[0, 1], x.closeness[0, 0], atol=1e-6)
    assert torch.allclose(x.params[0, :, :9], torch.eye(3).flatten().expand(2, 9), atol=1e-6)
    assert x.params[0, :, 9].tolist() == [1.0, 2.0] and x.params[1, 1, 9] == 0
    assert torch.isfinite(x.params).all()
    # the default sharp kernel keeps the vertical line for A_y only
    sharp = fsnet_inputs(images, segments, mask, fr, size=size).closeness
    assert torch.allclose(sharp[0, 0, 1, 25:55, col], torch.ones(30)) and (sharp[0, 0, [0, 2], 25:55, col] == 0).all()
    assert not ((sharp > 0) & (sharp < 1e-6)).any()  # no subnormal floats from the kernel's tail


def test_chunked_drawing_matches_drawing_all_channels_at_once():
    g = torch.Generator().manual_seed(0)
    segments = torch.rand(2, 40, 2, 2, generator=g) * 80 - 10  # some leave the map
    mask = torch.rand(2, 40, generator=g) > 0.3
    values = torch.rand(2, 40, 30, generator=g, requires_grad=True)
    reference = rasterize_segments(segments, mask, values, 50, 60, chunk_channels=30)
    drawn = rasterize_segments(segments, mask, values, 50, 60, chunk_channels=7)
    assert torch.equal(drawn, reference)
    weights = torch.rand(reference.shape, generator=g)
    (grad_ref,) = torch.autograd.grad((reference * weights).sum(), values)
    (grad,) = torch.autograd.grad((drawn * weights).sum(), values)
    assert torch.allclose(grad, grad_ref)
    with torch.no_grad():  # chunked in place
        assert torch.equal(rasterize_segments(segments, mask, values, 50, 60, chunk_channels=7), reference)


def random_scene(width: int, height: int = 48):
    """Two images with 30 random segments each (some masked) and 6 random frames: (segments, mask, frames, images)."""
    g = torch.Generator().manual_seed(1)
    segments = torch.rand(2, 30, 2, 2, generator=g) * torch.tensor([float(width), float(height)])
    mask = torch.rand(2, 30, generator=g) > 0.2
    R = rotation_from_angles(torch.rand(12, generator=g) * 20, torch.rand(12, generator=g) * 10).view(2, 6, 3, 3)
    return segments, mask, frames(R, torch.rand(2, 6, generator=g) + 0.8), torch.rand(2, 3, height, width, generator=g)


def test_shared_variant_scores_pooled_maps_as_the_full_maps():
    net = tiny("shared", input_size=32).eval()  # stride 8: pooled to 4 x 4
    segments, mask, fr, images = random_scene(80)
    full = fsnet_inputs(images, segments, mask, fr, 32)
    pooled = net.prepare_inputs(images, segments, mask, fr)
    assert net.pool_cell(32, 32) == 8 and pooled.closeness.shape == (2, 6, 3, 4, 4)
    assert torch.equal(pooled.line_map, full.line_map)
    torch.testing.assert_close(net(*pooled), net(*full))
    with pytest.raises(Exception, match="pooled by 8"):
        net(full.images, full.line_map, full.closeness[..., :16, :16], full.params)


def test_full_maps_where_the_network_cannot_take_pooled_ones():
    assert tiny("faithful").pool_cell(32, 32) is None
    assert tiny("shared").pool_cell(36, 32) is None  # not a multiple of the stride
    assert tiny("shared", use_maps=False).pool_cell(32, 32) is None
    net = tiny("faithful", input_size=32)
    x = net.prepare_inputs(
        torch.rand(1, 3, 40, 40),
        torch.rand(1, 3, 2, 2) * 40,
        torch.ones(1, 3, dtype=torch.bool),
        frames(torch.eye(3).expand(1, 2, 3, 3), torch.ones(1, 2)),
    )
    assert x.closeness.shape == (1, 2, 3, 32, 32)


def test_closeness_maps_pass_gradients_to_the_frames():
    R = rotation_from_angles(torch.tensor([3.0, -4.0]), torch.tensor([2.0, 1.0]), torch.tensor([10.0, 30.0]))
    R = R[None].requires_grad_(True)
    segments = torch.tensor([[[[30.0, 10.0], [32.0, 60.0]], [[5.0, 40.0], [70.0, 35.0]]]])
    fr = frames(R, torch.tensor([[1.3, 1.1]]))
    x = fsnet_inputs(torch.rand(1, 3, 64, 80), segments, torch.ones(1, 2, dtype=torch.bool), fr, 32, kernel_angle=None)
    x.closeness.sum().backward()
    assert torch.isfinite(R.grad).all() and R.grad.abs().sum() > 0


def test_canonical_vps_ignore_axis_labels():
    R = rotation_from_angles(torch.tensor([8.0]), torch.tensor([-5.0]), torch.tensor([20.0]))[0]
    relabelled = torch.stack([R[:, 2], R[:, 1], -R[:, 0]], -1)  # yaw + 90 degrees: the same Manhattan frame
    flipped = torch.stack([-R[:, 0], R[:, 1], -R[:, 2]], -1)  # yaw + 180 degrees
    vps = canonical_frame_vps(frames(torch.stack([R, relabelled, flipped])[None], torch.full((1, 3), 1.5)))
    assert torch.allclose(vps[0, 1], vps[0, 0], atol=1e-6) and torch.allclose(vps[0, 2], vps[0, 0], atol=1e-6)
    assert vps[0, 0, 1, 1] > 0 and vps[0, 0, 2, 2] > 0  # vertical points down, third axis forward


@pytest.mark.parametrize("variant", ["faithful", "shared"])
def test_gradients_reach_the_image_pixels(variant):
    net = tiny(variant, input_size=40).train()
    images = torch.rand(2, 3, 48, 80, requires_grad=True)
    segments = torch.tensor([[[5.0, 5.0], [5.0, 40.0]], [[10.0, 20.0], [70.0, 22.0]]]).expand(2, 2, 2, 2)
    fr = frames(torch.eye(3).expand(2, 3, 3, 3), torch.full((2, 3), 1.2))
    x = net.prepare_inputs(images, segments, torch.ones(2, 2, dtype=torch.bool), fr)
    assert x.images.shape[-1] == net.input_size
    net(*x).sum().backward()
    assert torch.isfinite(images.grad).all() and images.grad.abs().sum() > 0


@pytest.mark.parametrize("variant", ["faithful", "shared"])
def test_settings_rebuild_the_network(variant):
    net = tiny(variant, norm="group", use_image=False, kernel_angle=None).eval()
    again = FSNet(**net.settings()).eval()
    again.load_state_dict(net.state_dict())
    inputs = random_inputs(1, 2)
    assert torch.equal(again(*inputs), net(*inputs))
    assert again.settings() == net.settings()


def test_custom_backbone():
    backbone = ResNet(4, (8,), (1,), norm="group")
    net = FSNet("shared", backbone=backbone, head_width=8).eval()
    assert net(*random_inputs(1, 3)).shape == (1, 3)
    with pytest.raises(ValueError, match="custom backbone"):
        net.settings()
    with pytest.raises(Exception, match="takes 4 channels, FSNet feeds 17"):
        FSNet("faithful", backbone=backbone)


def test_resnet18_layout_and_strides():
    net = ResNet(3, *LAYOUTS["resnet18"])
    # torchvision's resnet18 without its classifier: 11,689,512 - 513,000 parameters
    assert sum(p.numel() for p in net.parameters()) == 11_176_512
    assert net.out_channels == 512 and net.stride == 32
    small = ResNet(17, (8, 16, 32), (1, 2, 1), norm="group")
    assert small(torch.rand(2, 17, 64, 48)).shape == (2, 32, 4, 3)
    assert small.pooled(torch.rand(2, 17, 64, 48)).shape == (2, 32)
    assert ResNet(**small.settings()).settings() == small.settings()
    with pytest.raises(ValueError, match="unknown norm"):
        ResNet(3, (8,), (1,), norm="layer")


@pytest.mark.parametrize("stride", [1, 2])
def test_the_trunks_convolutions_at_inference_match_torchs_choice(stride):
    # one image's small maps take oneDNN's kernel at inference (torch would take its slower im2col path there):
    # the same convolution to float round-off; with gradients recorded torch's own path runs, and they flow
    from ngp_kornia.nets.resnet import Conv3x3

    torch.manual_seed(0)
    conv = Conv3x3(64, 32, stride).eval()
    plain = torch.nn.Conv2d(64, 32, 3, stride, 1, bias=False)
    plain.load_state_dict(conv.state_dict())
    x = torch.rand(1, 64, 16, 16).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        torch.testing.assert_close(conv(x), plain(x), rtol=1e-5, atol=1e-5)
    x.requires_grad_()
    out = conv(x)
    assert torch.equal(out, plain(x))
    out.sum().backward()
    assert x.grad is not None and conv.weight.grad is not None
    with torch.no_grad():  # other dtypes: torch's choice
        assert torch.equal(conv.double()(x.double()), plain.double()(x.double()))


def test_support_features_count_the_lines_through_each_vp():
    # a vertical segment (length 80) and a horizontal one (length 160), identity frame: VP 0 = x, VP 1 = y
    segments = torch.tensor([[[[50.0, 10.0], [50.0, 90.0]], [[20.0, 30.0], [180.0, 30.0]]]])
    mask = torch.ones(1, 2, dtype=torch.bool)
    tilt = rotation_from_angles(torch.tensor([0.0]), torch.tensor([3.0]), torch.tensor([0.0]))  # 3 degrees of roll
    R = torch.stack([torch.eye(3), tilt[0]])[None]
    fr = frames(R, torch.tensor([[1.0, 1.0]]))
    params = fsnet_inputs(torch.rand(1, 3, 100, 200), segments, mask, fr, size=32, support=True).params
    assert params.shape == (1, 2, NUM_PARAMS + NUM_SUPPORT)
    support = params[0, :, NUM_PARAMS:].reshape(2, len(SUPPORT_ANGLES), 4)  # (frame, angle, VP 0 / 1 / 2 / closest)
    assert torch.allclose(support[0, :, 0], torch.full((5,), 2 / 3))
    assert torch.allclose(support[0, :, 1], torch.full((5,), 1 / 3))
    assert torch.allclose(support[0, :, 3], torch.ones(5))
    # the rolled frame misses both lines by about 3 degrees: no support below that, full support at 4 degrees
    assert (support[1, :-1, 3] == 0).all() and float(support[1, -1, 3]) == pytest.approx(1.0)


def test_support_network_takes_thirty_parameters_and_rebuilds():
    net = tiny("shared", use_support=True).eval()
    images, lmap, close, _ = random_inputs(1, 3)
    params = torch.rand(1, 3, NUM_PARAMS + NUM_SUPPORT)
    assert net(images, lmap, close, params).shape == (1, 3)
    again = FSNet(**net.settings())
    assert again.use_support and again.num_params == NUM_PARAMS + NUM_SUPPORT
    with pytest.raises(Exception, match="30"):
        net(images, lmap, close, params[..., :NUM_PARAMS])


def test_shared_head_weights_are_channels_last_and_load_as_they_are():
    net = tiny("shared").eval()
    cl = torch.channels_last
    assert all(getattr(net, n).weight.is_contiguous(memory_format=cl) for n in ("map_proj", "conv1", "conv2"))
    # the layout is not part of the weights: a state dict in the default layout loads into it unchanged
    state = {k: v.contiguous() for k, v in net.state_dict().items()}
    again = FSNet(**net.settings()).eval()
    again.load_state_dict(state)
    assert again.state_dict().keys() == net.state_dict().keys()
    assert all(torch.equal(a, b) for a, b in zip(again.state_dict().values(), net.state_dict().values(), strict=True))
    assert again.conv1.weight.is_contiguous(memory_format=cl)
    inputs = random_inputs(2, 5)
    with torch.no_grad():
        assert torch.equal(again(*inputs), net(*inputs))


@pytest.mark.parametrize("kw", [{}, {"use_image": False}, {"use_image": False, "use_maps": False}])
def test_shared_head_scores_the_same_without_autograd(kw):
    net = tiny("shared", **kw).eval()
    inputs = random_inputs(2, 5)
    with torch.no_grad():
        fast = net(*inputs)
    assert torch.equal(fast, net(*inputs).detach())


def test_area_resize_is_opencvs_area_filter_with_gradients_for_the_pixels():
    import cv2
    import numpy as np

    from ngp_kornia.nets.fsnet_inputs import area_resize

    rgb = np.random.default_rng(0).integers(0, 256, (48, 80, 3), dtype=np.uint8)
    images = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255.0
    expected = cv2.resize(rgb.astype(np.float32) / 255.0, (40, 30), interpolation=cv2.INTER_AREA)  # the training filter
    out = area_resize(images, (30, 40))
    assert out.shape == (1, 3, 30, 40)
    np.testing.assert_allclose(out[0].permute(1, 2, 0).numpy(), expected, atol=1e-6)
    pixels = images.clone().requires_grad_(True)
    with_grad = area_resize(pixels, (30, 40))
    assert torch.equal(with_grad.detach(), out)  # the same values whether or not the pixels need gradients
    with_grad.sum().backward()
    assert torch.isfinite(pixels.grad).all() and pixels.grad.abs().sum() > 0


def test_the_trunk_computed_ahead_gives_the_same_scores():
    """The parser builds FSNet's frame-free inputs and runs the shared trunk before the frames are known; the
    scores are those of the inputs built all at once."""
    from ngp_kornia.nets.fsnet_inputs import fsnet_frame_inputs, fsnet_line_inputs, with_images

    net = tiny("shared", input_size=32).eval()
    segments, mask, fr, images = random_scene(64)
    with torch.no_grad():
        whole = net(*net.prepare_inputs(images, segments, mask, fr))
        size, cell = net.input_size, net.pool_cell(net.input_size, net.input_size)
        ahead = with_images(fsnet_line_inputs(segments, mask, (48, 64), size, cell), images)
        context = net.image_context(ahead)
        inputs = fsnet_frame_inputs(ahead, segments, mask, fr, net.kernel_angle, net.chunk_size, net.use_support)
        split = net(*inputs, context=context)
    assert context is not None and torch.equal(whole, split)
