"""The facade: calibrate()'s few parameters, priors passed in one mapping (a flat keyword says how), Pillow images and
uint8 tensors as inputs, device=, and the trained parser from NeuralGeometricParser.from_pretrained."""

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import ngp_kornia.api as api
import ngp_kornia.pipeline.parser as parser_module
from ngp_kornia import InputError, NeuralGeometricParser, calibrate
from ngp_kornia.api import load_parser
from ngp_kornia.pipeline import Calibration
from ngp_kornia.threads import pipeline_threads
from ngp_kornia.training.synth.render import render_scene

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rgb():
    return render_scene(2, (320, 240)).image


def _same(a: Calibration, b: Calibration) -> None:
    for name in Calibration.FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or torch.equal(x.cpu(), y.cpu()), name


def test_calibrate_has_at_most_eight_parameters():
    assert len(inspect.signature(calibrate).parameters) <= 8


@pytest.mark.parametrize("module", [api, parser_module])
def test_no_function_of_the_facade_or_the_parser_takes_more_than_eight_parameters(module):
    tree = ast.parse(Path(module.__file__).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            a = node.args
            count = len(a.posonlyargs + a.args + a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
            assert count <= 8, f"{node.name} takes {count} parameters"


@pytest.mark.parametrize("name, value", [("focal", 500.0), ("k1", "estimate"), ("shared_intrinsics", True)])
def test_a_prior_passed_as_a_keyword_says_how_to_pass_it(name, value):
    with pytest.raises(TypeError, match=rf"priors=\{{'{name}': {value!r}\}}, not {name}="):
        calibrate(torch.rand(3, 64, 64), **{name: value})


def test_an_unknown_keyword_or_prior_is_named_with_the_closest():
    with pytest.raises(TypeError, match="unexpected keyword argument 'sed'; did you mean seed"):
        calibrate(torch.rand(3, 64, 64), sed=1)
    with pytest.raises(InputError, match="unknown prior 'focla'; did you mean focal"):
        calibrate(torch.rand(3, 64, 64), priors={"focla": 500.0})
    with pytest.raises(InputError, match="priors must be a mapping"):
        calibrate(torch.rand(3, 64, 64), priors=500.0)


def test_a_mapping_and_a_priors_object_are_the_same_priors(rgb):
    from ngp_kornia import Priors

    _same(calibrate(rgb, priors={"fov_v": 50.0, "gravity": (2.0, 1.0)}),
          calibrate(rgb, priors=Priors(fov_v=50.0, gravity=(2.0, 1.0))))


def test_a_pillow_image_is_its_pixels_as_displayed(rgb, tmp_path):
    _same(calibrate(Image.fromarray(rgb)), calibrate(rgb))
    path = tmp_path / "turned.png"
    exif = Image.Exif()
    exif[0x0112] = 6  # stored turned: displayed a quarter turn clockwise
    Image.fromarray(np.ascontiguousarray(np.rot90(rgb))).save(path, exif=exif)
    with Image.open(path) as opened:
        from_pillow = calibrate(opened)
    from_file = calibrate(path)
    _same(from_pillow, from_file)
    assert int(from_pillow.exif_orientation) == 6
    grey = calibrate(Image.fromarray(rgb).convert("L"))
    assert tuple(grey.image_size.tolist()) == (240, 320)


def test_a_uint8_tensor_is_its_pixels_over_255(rgb):
    image = torch.from_numpy(rgb).permute(2, 0, 1)
    _same(calibrate(image), calibrate(image.float() / 255))
    batch = torch.stack([image, image.flip(-1)])
    assert calibrate(batch).K.shape == (2, 3, 3)


def test_device_cpu_and_a_bad_device(rgb):
    _same(calibrate(rgb, device="cpu"), calibrate(rgb))
    with pytest.raises(InputError, match="device must be a torch device"):
        calibrate(rgb, device="gpu0")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            calibrate(rgb, device="cuda")


def test_from_pretrained_is_the_parser_calibrate_runs(rgb):
    parser = NeuralGeometricParser.from_pretrained()
    assert parser.zsnet is not None and parser.fsnet is not None and parser.config.evidence.enabled
    assert sum(p.numel() for p in parser.parameters()) > 0
    image = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    with torch.inference_mode(), pipeline_threads(None):  # the thread count calibrate() computes with
        direct = parser(image)[0]
    _same(direct.clone(), calibrate(image[0]))
    assert NeuralGeometricParser.from_pretrained("none", {"evidence.enabled": True}).config.evidence.enabled
    assert not NeuralGeometricParser.from_pretrained("full").config.evidence.enabled  # "default" adds its settings
    assert type(load_parser("zsnet")) is NeuralGeometricParser and load_parser("zsnet").fsnet is None


def test_the_facade_module_stays_short():
    assert len((ROOT / "ngp_kornia" / "api.py").read_text().splitlines()) < 250
