"""How far to trust a calibration: a calibrated confidence and per-parameter standard deviations.

The parser already knows more than its best score: whether a clearly different horizon scored almost as well (an
ambiguous image), whether the image's lines support a clearly different horizon nearly as well (the horizon search
of :mod:`ngp_kornia.pipeline.horizon`), how far its top-k frames disagree, how many lines it saw and how many of them
support the chosen frame. :func:`~ngp_kornia.pipeline.trust_features.trust_features` gathers these per image;
:class:`TrustModel` maps them to

* ``confidence``: the predicted probability that the horizon error is below ``threshold`` image heights (0.02), a
  logistic model of the features;
* ``pitch_std``, ``roll_std``, ``fov_v_std``: standard deviations in degrees, each
  ``exp(a + b * log(spread) + c * logit(confidence))`` with ``spread`` the score-weighted spread of that parameter
  over the top-k frames, combined in quadrature with the error an uncertain principal point puts under every
  answer (:func:`principal_point_terms`): the parser assumes it at the image centre, and a principal point ``d``
  pixels off turns the viewing rays by about ``d / f``.

The coefficients are fitted on rendered scenes only (``benchmarks/fit_confidence.py`` writes
``ngp_kornia/weights/trust.json``), for the shipped default weight set; other weight sets get the same model.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import torch
from torch import Tensor

from ngp_kornia.geometry.frames import FrameCandidates
from ngp_kornia.pipeline.constants import constant_tensors
from ngp_kornia.pipeline.horizon import Refinement
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.settings import ScoringSettings, TrustSettings
from ngp_kornia.pipeline.trust_features import SharedInputs, TrustFeatures, trust_features

__all__ = [
    "INPUT_NAMES",
    "STD_SPREADS",
    "TRUST_FILE",
    "TrustModel",
    "attach_trust",
    "confidence_inputs",
    "principal_point_terms",
]


#: the shipped coefficients (written by benchmarks/fit_confidence.py)
TRUST_FILE = Path(__file__).resolve().parent.parent / "weights" / "trust.json"


def confidence_inputs(features: TrustFeatures) -> Tensor:
    """The logistic model's inputs (B, D) from the features (transformed to roughly linear effects)."""
    return torch.stack(
        [
            torch.log(features.score + 1e-3),
            torch.log(features.manhattan + 1e-3),
            features.ambiguity,
            torch.log(features.horizon_spread + 1e-3),
            torch.log1p(features.lines),
            features.vertical_share,
            features.horizontal_share,
            features.valid_share,
            features.support_rival**4,  # its effect lies near 1, where a rival is nearly as well supported
        ],
        -1,
    )


#: names of the columns of :func:`confidence_inputs`, as stored in the coefficients file
INPUT_NAMES = (
    "log_score",
    "log_manhattan",
    "ambiguity",
    "log_horizon_spread",
    "log_lines",
    "vertical_share",
    "horizontal_share",
    "valid_share",
    "support_rival_4",
)


#: the parameters with a standard deviation, and the feature their spread comes from
STD_SPREADS = {"pitch": "pitch_spread", "roll": "roll_spread", "fov_v": "fov_spread"}


@dataclass(frozen=True)
class TrustModel:
    """Coefficients of the confidence and of the standard deviations.

    Attributes:
        threshold: horizon error (image heights) the confidence is the probability of staying under.
        weights: (D,) logistic weights on the standardised :func:`confidence_inputs`.
        bias: logistic bias.
        mean: (D,) input means used to standardise.
        scale: (D,) input standard deviations used to standardise.
        std: per parameter (``pitch``, ``roll``, ``fov_v``) ``(a, b, c)`` of
            ``log(std) = a + b * log(spread + 0.01) + c * logit(confidence) + e * log(line_residual + 0.05)``.
        residual_exponent: ``e`` above (0 for files without it). The shipped model fixes it at 1, as a VP's
            direction error grows in proportion to its lines' angular noise; ``a``, ``b``, ``c`` are fitted.
        principal_point: per parameter the gain ``k`` of the principal-point term of :func:`principal_point_terms`
            (0 for all when the file has none).
    """

    threshold: float
    weights: tuple[float, ...]
    bias: float
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    std: dict[str, tuple[float, float, float]]
    principal_point: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STD_SPREADS, 0.0))
    residual_exponent: float = 0.0

    @classmethod
    def load(cls, path: str | Path = TRUST_FILE) -> TrustModel:
        """Read a coefficients file written by ``benchmarks/fit_confidence.py``."""
        data = json.loads(Path(path).read_text())
        if tuple(data["inputs"]) != INPUT_NAMES:
            raise ValueError(f"{path}: its inputs {data['inputs']} are not this version's {list(INPUT_NAMES)}")
        return cls(
            threshold=float(data["threshold"]),
            weights=tuple(data["weights"]),
            bias=float(data["bias"]),
            mean=tuple(data["mean"]),
            scale=tuple(data["scale"]),
            std={k: tuple(v) for k, v in data["std"].items()},
            principal_point={k: float(data.get("principal_point", {}).get(k, 0.0)) for k in STD_SPREADS},
            residual_exponent=float(data.get("residual_exponent", 0.0)),
        )

    def confidence(self, features: TrustFeatures) -> Tensor:
        """(B,) probability that the horizon error is below :attr:`threshold`."""
        x = confidence_inputs(features)
        mean, scale, weights = constant_tensors((self.mean, self.scale, self.weights), x.dtype, x.device)
        return torch.sigmoid(((x - mean) / scale) @ weights + self.bias)

    def stds(
        self, features: TrustFeatures, confidence: Tensor, floor: dict[str, Tensor] | None = None
    ) -> dict[str, Tensor]:
        """Standard deviations (B,) in degrees of ``pitch``, ``roll`` and ``fov_v``.

        Args:
            features: the trust features.
            confidence: (B,) the confidence.
            floor: per parameter (B,) the unscaled principal-point terms of :func:`principal_point_terms`, degrees;
                each is scaled by :attr:`principal_point` and added in quadrature. None: a known principal point.
        """
        p = confidence.clamp(1e-4, 1 - 1e-4)
        logit = torch.log(p) - torch.log1p(-p)
        # the three parameters side by side, (B, 3): the same arithmetic per element as one at a time
        spread = torch.stack([getattr(features, spread) for spread in STD_SPREADS.values()], -1)
        coefficients = tuple(zip(*(self.std[name] for name in STD_SPREADS), strict=True))
        a, b, c = constant_tensors(coefficients, spread.dtype, spread.device)
        noise = self.residual_exponent * torch.log(features.line_residual + 0.05)
        out = torch.exp(a + b * torch.log(spread + 0.01) + c * logit[:, None] + noise[:, None])
        if floor is not None:
            gains = (tuple(self.principal_point[name] for name in STD_SPREADS),)
            (gain,) = constant_tensors(gains, out.dtype, out.device)
            out = torch.hypot(out, gain * torch.stack([floor[name] for name in STD_SPREADS], -1))
        return dict(zip(STD_SPREADS, out.unbind(-1), strict=True))


def principal_point_terms(
    principal_point_std: float | Tensor, focal: Tensor, height: int, pitch: Tensor
) -> dict[str, Tensor] | None:
    """The errors (degrees, (B,)) a principal point ``principal_point_std * height`` pixels off the centre along
    each axis puts under the answer, before the model's per-parameter gains; None when the option is 0.

    A principal point ``d = (dx, dy)`` pixels off the assumed centre turns the viewing rays by about ``d / f``
    radians. ``dy`` tilts the camera: pitch ``sigma / f``. ``dx`` turns it about its own vertical axis, which moves
    the up vector sideways in proportion to its forward component: roll ``sigma / f * |tan(pitch)|`` (nothing for a
    level camera, whose horizon slope a principal point cannot change). The focal length of two or three vanishing
    points moves by a multiple of ``d`` (``f^2 = -(v_1 - c) . (v_2 - c)``), and the vertical field of view with it:
    ``d fov_v / d f = -H / (f^2 + H^2 / 4)``. The gains are fitted on renders with off-centre principal points
    (``benchmarks/fit_confidence.py principal-point``).

    Args:
        principal_point_std: standard deviation per axis, a fraction of the image height: one for all, or (B,).
        focal: (B,) the answer's focal length, pixels.
        height: image height, pixels.
        pitch: (B,) the answer's pitch, degrees.

    Example:
        >>> terms = principal_point_terms(0.02, torch.tensor([480.0]), 480, torch.tensor([45.0]))
        >>> terms["pitch"], terms["roll"]  # 9.6 px at f = 480: 1.15 degrees, times tan(45) for the roll
        (tensor([1.1459]), tensor([1.1459]))
    """
    # float64 until each term meets the focal length, then a reciprocal times it, as a Python number divided by a
    # tensor is computed: the same bits for one deviation for all images and for one per image
    std = torch.as_tensor(principal_point_std, dtype=torch.float64, device=focal.device)
    if not bool((std != 0).any()):
        return None
    sigma = std * height
    f = focal.clamp_min(1e-6)
    ray = torch.rad2deg(f.reciprocal() * sigma.to(f))
    tilt = torch.tan(torch.deg2rad(pitch.abs().clamp_max(80.0)))
    return {
        "pitch": ray,
        "roll": ray * tilt,
        "fov_v": torch.rad2deg((f.square() + height**2 / 4.0).reciprocal() * (sigma * height).to(f)),
    }


def _centre_std(trust: TrustSettings | float | Tensor | None) -> float | Tensor:
    """The principal point's standard deviation of :func:`attach_trust`'s ``trust``."""
    settings = trust is None or isinstance(trust, TrustSettings)
    return (trust or TrustSettings()).centre_std if settings else trust


def _detached(t: Tensor) -> Tensor:
    """``t.detach()``, skipped (a few microseconds per tensor) for a tensor that holds no gradient."""
    return t.detach() if t.requires_grad else t


@lru_cache(maxsize=1)
def _shipped() -> TrustModel:
    return TrustModel.load(TRUST_FILE)


def attach_trust(
    result: Calibration,
    frames: FrameCandidates,
    scores: Tensor,
    segments: Tensor,
    mask: Tensor,
    scoring: ScoringSettings | None = None,
    trust: TrustSettings | float | Tensor | None = None,
    known_focal: bool = False,
    model: TrustModel | None = None,
    shared: SharedInputs | None = None,
    refinement: Refinement | None = None,
    residual_vps: Tensor | None = None,
) -> Calibration:
    """The answer with ``confidence``, ``pitch_std``, ``roll_std`` and ``fov_v_std`` filled in.

    An image without a valid frame gets confidence 0 and standard deviations of 90 degrees (pitch, roll) and 180
    (field of view): nothing is known. With a known focal length the field of view's standard deviation is 0.
    Computed without gradients: these are diagnostics, not part of the differentiable answer.

    Args:
        result: the batched answer of the parser.
        frames: its scored frame candidates.
        scores: (B, F) their scores.
        segments: (B, N, 2, 2) segments, input pixels.
        mask: (B, N) bool.
        scoring: the frame scores' settings (``top_k``, ``kernel_angle``); None for the defaults.
        trust: the settings' ``centre_std`` (how uncertain the principal point is), or that fraction of
            the height itself (one number, or (B,) one per image); None for the defaults.
        known_focal: the focal length was given as a prior.
        model: coefficients; None uses the shipped ones.
        shared: the same call's lines, lengths and top-k weights (:class:`SharedInputs`), when already computed.
        refinement, residual_vps: the horizon search of the same call, when already run, and the VPs of the line
            residual (see :func:`~ngp_kornia.pipeline.trust_features.trust_features`).

    Returns:
        a new :class:`Calibration`.
    """
    model, scoring, centre_std = model or _shipped(), scoring or ScoringSettings(), _centre_std(trust)
    with torch.no_grad():
        frames = FrameCandidates(**{k: _detached(v) for k, v in frames.__dict__.items()})
        if shared is not None:
            shared = SharedInputs(*(_detached(t) for t in shared))
        if refinement is not None:
            refinement = Refinement(*(_detached(t) for t in refinement))
        features = trust_features(
            result, frames, scores, segments, mask, scoring.top_k, scoring.kernel_angle, shared, refinement,
            residual_vps,
        )  # fmt: skip
        conf = model.confidence(features)
        height = int(result.image_size[0, 0].item())
        floor = principal_point_terms(centre_std, result.focal.detach(), height, result.pitch.detach())
        stds = model.stds(features, conf, floor)
    valid = result.valid
    conf = torch.where(valid, conf, 0.0)
    pitch_std = torch.where(valid, stds["pitch"], 90.0)
    roll_std = torch.where(valid, stds["roll"], 90.0)
    fov_std = torch.zeros_like(stds["fov_v"]) if known_focal else torch.where(valid, stds["fov_v"], 180.0)
    return replace(result, confidence=conf, pitch_std=pitch_std, roll_std=roll_std, fov_v_std=fov_std)
