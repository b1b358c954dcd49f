"""Methods to evaluate: this package's ``calibrate()`` under a weights spec, the peer lu-vp-detect (Lu et al., WACV
2017, given the true focal length and principal point) and a level-horizon baseline, each a function
``LabelledImage -> Estimate``; and :func:`run_interleaved`, which runs several of them image by image and times them.
"""

from __future__ import annotations

import math
import sys
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO

import cv2
import numpy as np
import torch
from torch import Tensor

from ngp_kornia.evaluation.datasets import LabelledImage
from ngp_kornia.geometry.camera import horizon_from_zenith, image_center, pitch_roll_from_up, zenith_from_up
from ngp_kornia.pipeline import Calibration, NeuralGeometricParser, ParserConfig
from ngp_kornia.pipeline.camera_model import option_values
from ngp_kornia.pipeline.priors import CALL_PRIORS, PRIOR_NAMES, Priors
from ngp_kornia.pipeline.segments import longest_segments, pad_segments
from ngp_kornia.pipeline.settings import locate_setting

__all__ = [
    "CALL_ARGUMENTS",
    "Estimate",
    "Method",
    "MethodRun",
    "calibrate_method",
    "calibrate_segments",
    "calibration_method",
    "call_arguments",
    "estimate_from_calibration",
    "failed_estimate",
    "gravity_prior",
    "level_centre",
    "lu_vp_detect_method",
    "parse_weights_spec",
    "run_interleaved",
    "weights_and_config",
]


@dataclass
class Estimate:
    """One method's answer for one image, in this package's conventions (float64, degrees).

    Attributes:
        up: (3,) up vector in camera coordinates.
        horizon: (3,) horizon line in pixels.
        pitch: degrees.
        roll: degrees.
        fov_v: vertical field of view in degrees; ``None`` when the method does not estimate it.
        extra: per-image values kept with the errors (e.g. ``focal``, ``valid``, ``score``).
    """

    up: Tensor
    horizon: Tensor
    pitch: float
    roll: float
    fov_v: float | None = None
    extra: dict = field(default_factory=dict)


#: a method under evaluation
Method = Callable[[LabelledImage], Estimate]


def failed_estimate() -> Estimate:
    """The estimate of a method that raised: NaN everywhere, counted as a failure (and a miss in the AUC)."""
    nan3 = torch.full((3,), math.nan, dtype=torch.float64)
    return Estimate(nan3, nan3.clone(), math.nan, math.nan, math.nan)


def estimate_from_calibration(result: Calibration) -> Estimate:
    """The fields of one image's :class:`ngp_kornia.Calibration` that the evaluation uses, as float64 on the CPU;
    ``focal``, ``valid``, ``score`` and the camera options
    (:func:`~ngp_kornia.pipeline.camera_model.option_values`) go to :attr:`Estimate.extra`."""

    def f64(t: Tensor) -> Tensor:
        return t.detach().cpu().double()

    return Estimate(
        up=f64(result.up),
        horizon=f64(result.horizon),
        pitch=float(result.pitch),
        roll=float(result.roll),
        fov_v=float(result.fov_v),
        extra={
            "focal": float(result.focal),
            "valid": bool(result.valid),
            "score": float(result.score),
            **option_values(result),
        },
    )


def parse_weights_spec(spec: str | None) -> tuple[str | list[str], dict[str, str | bool]]:
    """``NAME[:key=value,...]`` -> (weights for ``calibrate``, ParserConfig overrides as text or bool).

    NAME is a weight set (none, zsnet, fsnet, full, default) or .pt paths joined by ``+``; the overrides set
    :class:`ngp_kornia.ParserConfig` fields, e.g. ``full:top_k=1`` or ``fsnet:use_manhattan=false``, or name
    ``calibrate()``'s call arguments (:data:`CALL_ARGUMENTS`, read by :func:`calibrate_method`).

    Example:
        >>> parse_weights_spec("full:top_k=4,use_manhattan=false")
        ('full', {'top_k': '4', 'use_manhattan': False})
        >>> parse_weights_spec("a.pt+b.pt")
        (['a.pt', 'b.pt'], {})
    """
    if spec is None:
        return "default", {}
    name, _, rest = spec.partition(":")
    weights: str | list[str] = name.split("+") if "+" in name else name
    overrides: dict[str, str | bool] = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        overrides[key] = {"true": True, "false": False}.get(value.lower(), value)
    return weights, overrides


def weights_and_config(spec: str | None) -> tuple[str | list[str], ParserConfig]:
    """A weights spec (see :func:`parse_weights_spec`) -> (weights for ``calibrate``, ParserConfig with the overrides).

    Overrides name a setting as ``stage.field`` or by a field name only one stage has (``top_k``,
    ``horizon.refine``); ``seed`` is not a setting and is read by :func:`calibrate_method`.

    Raises:
        ValueError: an override names no setting, or its value does not convert to the setting's type.

    Example:
        >>> weights, config = weights_and_config("full:top_k=4")
        >>> weights, config.scoring.top_k
        ('full', 4)
    """
    weights, overrides = parse_weights_spec(spec)
    overrides.pop("seed", None)
    for name in CALL_ARGUMENTS:
        overrides.pop(name, None)
    values = {}
    for key, value in overrides.items():
        try:
            stage, name = locate_setting(key)
        except ValueError as err:
            raise ValueError(f"{err} (in the weights spec {spec!r})") from None
        values[f"{stage}.{name}"] = _converted(value, getattr(getattr(ParserConfig(), stage), name), key, spec)
    from ngp_kornia.api import weight_set_config

    return weights, weight_set_config(weights, values)


def _converted(value: str | bool, default: object, key: str, spec: str | None) -> object:
    if isinstance(value, bool) or isinstance(default, bool):
        return value
    kind = type(default)
    try:
        return tuple(float(v) for v in value.split("/")) if kind is tuple else kind(value)
    except ValueError:
        raise ValueError(f"{key}={value!r} in the weights spec {spec!r} is not a {kind.__name__}") from None


#: the spec keys that are ``calibrate()``'s priors rather than settings: any prior as ``NAME=VALUE`` (a number, or
#: ``estimate`` for the camera options that are estimated), ``shared_intrinsics=true``
#: (the whole set as one camera), ``gravity_noise=DEG`` (a gravity prior from the image's true pitch and roll plus
#: Gaussian noise of that standard deviation, drawn from the seed and the image's name) and ``gravity_std=DEG`` (the
#: prior's stated standard deviation; ``gravity_noise`` by default)
CALL_ARGUMENTS = (*PRIOR_NAMES, *CALL_PRIORS, "gravity_noise")


def call_arguments(spec: str | None) -> dict:
    """The call arguments of a spec (:data:`CALL_ARGUMENTS`), their values converted.

    Example:
        >>> call_arguments("default:focal=500,gravity_noise=1,top_k=4")
        {'focal': 500.0, 'gravity_noise': 1.0}
    """
    overrides = parse_weights_spec(spec)[1]
    out: dict = {}
    for name in CALL_ARGUMENTS:
        if name not in overrides:
            continue
        value = overrides[name]
        try:
            out[name] = value if value == "estimate" or isinstance(value, bool) else float(value)
        except ValueError:
            raise ValueError(f"{name}={value!r} in the weights spec {spec!r} is not a number or 'estimate'") from None
    return out


def gravity_prior(image: LabelledImage, seed: int, noise: float) -> tuple[float, float]:
    """The image's true ``(pitch, roll)`` plus Gaussian noise of ``noise`` degrees, drawn from ``seed`` and the
    image's name (the same for every run of one seed).

    Raises:
        ValueError: the image has no true pitch and roll.
    """
    if image.pitch is None or image.roll is None:
        raise ValueError(f"{image.name}: a gravity prior from the ground truth needs its pitch and roll")
    rng = np.random.default_rng([seed, zlib.crc32(image.name.encode())])
    dp, dr = rng.normal(0.0, noise, 2) if noise > 0 else (0.0, 0.0)
    return float(image.pitch + dp), float(image.roll + dr)


def calibrate_method(
    spec: str | None = None, seed: int | None = None, images: Sequence[LabelledImage] | None = None
) -> Method:
    """:func:`ngp_kornia.calibrate` on the image file under a weights spec, as a method.

    Args:
        spec: weights spec (:func:`parse_weights_spec`, with the :data:`CALL_ARGUMENTS`); ``None`` is the package
            default.
        seed: sampling seed; ``None`` keeps the spec's (``seed=...``, 0 unless given).
        images: the whole set, for ``shared_intrinsics=true``: its first call calibrates them all as one camera
            (that call's time is the set's; the others only look the answer up).
    """
    calibration = calibration_method(spec, seed, images)
    return lambda image: estimate_from_calibration(calibration(image))


def calibration_method(
    spec: str | None = None, seed: int | None = None, images: Sequence[LabelledImage] | None = None
) -> Callable[[LabelledImage], Calibration]:
    """The :class:`~ngp_kornia.Calibration` that :func:`calibrate_method` (same arguments) reads its estimate from:
    what the worst-case sheets draw (:mod:`~ngp_kornia.evaluation.sheets`)."""
    from ngp_kornia.api import calibrate

    weights, config = weights_and_config(spec)
    if seed is None:
        seed = int(parse_weights_spec(spec)[1].get("seed", 0))
    extra = call_arguments(spec)
    noise, stated = extra.pop("gravity_noise", None), extra.pop("gravity_std", None)
    options = {"weights": weights, "seed": seed, "config": config}
    if extra.pop("shared_intrinsics", False):
        return _shared_method(images, {**options, "priors": {**extra, "shared_intrinsics": True}})

    on_segments = _segment_parser(weights, config)

    def run(image: LabelledImage) -> Calibration:
        prior = {}
        if noise is not None:
            prior = {"gravity": gravity_prior(image, seed, noise), "gravity_std": stated or max(noise, 0.1)}
        if image.segments is not None:
            known = {name: value for name, value in extra.items() if name in PRIOR_NAMES}
            return calibrate_segments(on_segments(), image, seed, Priors(**{**prior, **known}))
        return calibrate(str(image.image_path), **options, priors={**extra, **prior})

    return run


def _segment_parser(weights, config: ParserConfig) -> Callable[[], NeuralGeometricParser]:
    """The parser of a weights spec for scenes given as segments, built at its first use: the spec's networks that
    read only segments (ZSNet, the line evidence); those that read pixels (FSNet, the orientation check) have
    none to read, so frames are ranked by the Manhattan score alone and no turn is read."""
    from ngp_kornia.api import check_weights

    built: list[NeuralGeometricParser] = []

    def parser() -> NeuralGeometricParser:
        if not built:
            nets = {type(net).__name__: net for net in check_weights(weights)}
            settings = config.replace(**{"upright.enabled": False})
            built.append(NeuralGeometricParser(settings, nets.get("ZSNet"), None, nets.get("LineEvidenceNet")).eval())
        return built[0]

    return parser


def calibrate_segments(parser: NeuralGeometricParser, image: LabelledImage, seed: int, priors: Priors) -> Calibration:
    """One scene given as segments (:attr:`LabelledImage.segments`) calibrated by ``parser``: the segments the
    detection would keep (:func:`~ngp_kornia.pipeline.segments.longest_segments`), an image of the scene's size that
    no network reads.

    Returns:
        the unbatched :class:`~ngp_kornia.Calibration`.
    """
    settings = parser.config.segments
    kept = longest_segments(image.segments.numpy(), settings.min_length, settings.max_segments)
    segments, mask = pad_segments([kept])
    stand_in = torch.zeros((), dtype=torch.float32).expand(1, 3, image.height, image.width)
    with torch.inference_mode():
        return parser(stand_in, segments, mask, seed=seed, priors=priors)[0].clone()


def _shared_method(images: Sequence[LabelledImage] | None, options: dict) -> Callable[[LabelledImage], Calibration]:
    """The calibrations of ``shared_intrinsics=true``: the whole set calibrated as one camera at the first call."""
    from ngp_kornia.api import calibrate

    if not images:
        raise ValueError("shared_intrinsics=true needs the set's images (calibrate_method(..., images=...))")
    answers: dict[str, Calibration] = {}

    def run(image: LabelledImage) -> Calibration:
        if not answers:
            results = calibrate([str(im.image_path) for im in images], **options)
            answers.update({im.name: r for im, r in zip(images, results, strict=True)})
        return answers[image.name]

    return run


class _LSDReshaper:
    """OpenCV >= 5 returns LSD lines as (N, 4); lu-vp-detect indexes them as (N, 1, 4)."""

    def __init__(self, lsd) -> None:
        self._lsd = lsd

    def detect(self, image, *args, **kwargs):
        out = self._lsd.detect(image, *args, **kwargs)
        lines = out[0]
        if lines is not None:
            lines = np.asarray(lines).reshape(-1, 1, 4)
        return (lines, *out[1:])

    def __getattr__(self, name):
        return getattr(self._lsd, name)


class _Cv2Proxy:
    """Stands in for ``cv2`` inside ``lu_vp_detect.vp_detection`` only; everything else is the real module."""

    def __getattr__(self, name):
        return getattr(cv2, name)

    @staticmethod
    def createLineSegmentDetector(*args, **kwargs):  # noqa: N802 (OpenCV's name)
        return _LSDReshaper(cv2.createLineSegmentDetector(*args, **kwargs))


def lu_vp_detect_method() -> Method:
    """lu-vp-detect (the ``lu_vp_detect`` package, extra ``bench``) given the true focal length and principal point.

    Its VPs are unit directions in the OpenCV camera frame (x right, y down, z forward: it lifts a pixel p to
    ``(p - pp, f)``), checked against the York Urban ground truth. The vertical is the VP with the largest |y|.
    The method needs :attr:`LabelledImage.K`; it gives no field of view (it is handed the true one).

    Raises:
        ImportError: lu-vp-detect is not installed (``pip install 'ngp-kornia[bench]'``).
    """
    import lu_vp_detect.vp_detection as vp_detection
    from lu_vp_detect import VPDetection

    if not isinstance(vp_detection.cv2, _Cv2Proxy):
        vp_detection.cv2 = _Cv2Proxy()

    def run(image: LabelledImage) -> Estimate:
        bgr = cv2.imread(str(image.image_path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(image.image_path)
        if image.K is None:
            raise ValueError(f"{image.name}: lu-vp-detect needs the true focal length, and this image has no K")
        K = image.K
        detector = VPDetection(
            length_thresh=30, principal_point=(float(K[0, 2]), float(K[1, 2])), focal_length=float(K[0, 0]), seed=0
        )
        vps = torch.as_tensor(np.asarray(detector.find_vps(bgr), dtype=np.float64))
        if vps.shape != (3, 3) or not bool(torch.isfinite(vps).all()):
            raise RuntimeError("lu-vp-detect returned no valid vanishing points")
        v = vps[int(vps[:, 1].abs().argmax())]
        up = -v if v[1] > 0 else v
        up = up / up.norm()
        horizon = horizon_from_zenith(K[None], zenith_from_up(K[None], up[None]))[0]
        pitch, roll = pitch_roll_from_up(up[None])
        return Estimate(up, horizon, float(pitch[0]), float(roll[0]), None)

    return run


def level_centre(image: LabelledImage) -> Estimate:
    """The trivial baseline: a level camera, up = (0, -1, 0), horizon y = (H - 1) / 2 (through the image centre)."""
    up = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    centre = image_center(image.height, image.width, like=up)
    horizon = torch.cat([up.new_tensor([0.0, 1.0]), -centre[1:]])
    return Estimate(up, horizon, 0.0, 0.0, None)


@dataclass
class MethodRun:
    """What one method gave on a list of images.

    Attributes:
        estimates: one per image (:func:`failed_estimate` where the method raised).
        seconds: wall time of all the timed calls.
        exceptions: ``"name: error"`` for each image where the method raised.
    """

    estimates: list[Estimate] = field(default_factory=list)
    seconds: float = 0.0
    exceptions: list[str] = field(default_factory=list)

    @property
    def seconds_per_image(self) -> float:
        """Mean wall time of one call (NaN before any call)."""
        return self.seconds / len(self.estimates) if self.estimates else math.nan


def run_interleaved(
    methods: dict[str, Method], images: Sequence[LabelledImage], progress: TextIO | None = sys.stderr
) -> dict[str, MethodRun]:
    """Run every method on every image, image by image, timing each call.

    One untimed warm-up call per method comes first (on the first image). Then, for image ``i``, the methods run in
    their order rotated by ``i``, so a burst of load from other jobs hits each method alike. A method that raises
    gets :func:`failed_estimate` for that image and the error is kept in :attr:`MethodRun.exceptions`.

    Args:
        methods: name -> method.
        images: the images.
        progress: stream for a one-line progress counter, or ``None``.

    Returns:
        name -> :class:`MethodRun`, estimates in the order of ``images``.
    """
    names = list(methods)
    if not names:
        return {}
    for name in names:
        if images:
            try:
                methods[name](images[0])
            except Exception as e:  # reported again, per image, below
                print(f"[{name}] warm-up failed: {e!r}", file=progress or sys.stderr)
    runs = {name: MethodRun() for name in names}
    for i, image in enumerate(images):
        for name in names[i % len(names) :] + names[: i % len(names)]:
            start = time.perf_counter()
            try:
                estimate = methods[name](image)
            except Exception as e:
                estimate = failed_estimate()
                runs[name].exceptions.append(f"{image.name}: {e!r}")
            runs[name].seconds += time.perf_counter() - start
            runs[name].estimates.append(estimate)
        if progress is not None:
            print(f"\r{i + 1}/{len(images)} {image.name}", end="", file=progress, flush=True)
    if progress is not None and images:
        print(file=progress)
    return runs
