"""The orientation and structure check: how likely the image is the right way up and shows man-made structure.

Every answer of the parser assumes the photo is upright (its roll within about 45 degrees): the frame's axis closest to
the image's vertical is taken as up. A photo turned by 90 or 180 degrees without an orientation tag breaks that
assumption, and its lines cannot show it: they fit a camera rolled by 90 or 180 degrees exactly as well. An image with
no structure (noise, clouds, foliage) gives lines that support no camera at all. The
:class:`~ngp_kornia.nets.upright.UprightNet` reads the image's appearance and says how likely each case is (its
probabilities calibrated on real photos held back from its training), and where given an
:class:`~ngp_kornia.nets.upright_lines.UprightLinesNet` reads the turn from the detected segments, its reading fused
with the network's (:func:`fuse_line_reading`) before the prior is applied (:func:`with_prior`); the answer's
confidence, the probability that it is right, is multiplied by the probability that the assumption holds (an answer for
the wrong way up is never right). Where the check is sure of one turn, the answer reports it and is turned
(:func:`turned_answer`): the frame the lines found is the same whichever way the photo is held, only which of its axes
is up changes, so the camera of the turned photo is the one whose up axis that turn points up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import torch
from torch import Tensor, nn

from ngp_kornia.geometry.camera import canonical_manhattan_rotation
from ngp_kornia.pipeline.answer import level_answer
from ngp_kornia.pipeline.result import Calibration
from ngp_kornia.pipeline.segments import strip_threads
from ngp_kornia.threads import beside

__all__ = [
    "apply_upright",
    "fuse_line_reading",
    "read_beside",
    "read_lines_beside",
    "turned_answer",
    "upright_probabilities",
    "weigh_by_pitch",
    "with_prior",
]


def upright_probabilities(net: nn.Module, images: Tensor, prior: float = 0.5) -> Tensor:
    """(B, 5) probabilities of :data:`~ngp_kornia.nets.upright.CLASSES` for (B, 3, H, W) images in [0, 1], with
    ``prior`` the share of upright photos among those with structure.

    The network is trained on the four turns equally often; Bayes' rule moves its readings to the prior: each
    turn's probability is multiplied by its prior over the training share (1/4), the structure-free reading kept,
    and the five renormalised.

    Example:
        >>> from ngp_kornia.nets.upright import UprightNet
        >>> probs = upright_probabilities(UprightNet().eval(), torch.rand(1, 3, 48, 64), prior=0.25)
        >>> bool(torch.allclose(probs.sum(-1), torch.ones(1)))
        True
    """
    with torch.no_grad():
        return with_prior(net.probabilities(images.detach()), prior)


def with_prior(probs: Tensor, prior: float) -> Tensor:
    """(B, 5) probabilities read for the four turns equally often, moved to ``prior``, the share of upright photos
    among those with structure (Bayes' rule, as :func:`upright_probabilities` says).

    Example:
        >>> with_prior(torch.tensor([[0.2, 0.2, 0.2, 0.2, 0.2]]), 0.75)[0].tolist()
        [0.6000000238418579, 0.06666667014360428, 0.06666667014360428, 0.06666667014360428, 0.20000000298023224]
    """
    turns = probs.new_tensor([prior, *([(1.0 - prior) / 3] * 3)]) * 4.0
    weighed = torch.cat([probs[:, :4] * turns, probs[:, 4:]], -1)
    return weighed / weighed.sum(-1, keepdim=True)


def read_lines_beside(net: nn.Module, segments: Tensor, mask: Tensor, size: tuple[int, int]) -> Callable[[], Tensor]:
    """Start the :class:`~ngp_kornia.nets.upright_lines.UprightLinesNet` reading (B, 4) of the detected segments
    (B, N, 2, 2) of images of ``size`` (H, W) on the helper thread where the call may use two cores, and return
    the function that gives it (the same computation either way)."""

    def read() -> Tensor:
        with torch.no_grad():
            return net(segments.detach(), mask, *size)

    return read if strip_threads(2) < 2 else beside(read)


def fuse_line_reading(net: nn.Module, probs: Tensor, lines: Tensor) -> Tensor:
    """(B, 5) probabilities: the network's (B, 5) reading at a flat prior with its four turns fused with the lines'
    (B, 4) log-probabilities (:meth:`~ngp_kornia.nets.upright_lines.UprightLinesNet.fuse`); the structure-free
    reading kept as it is.

    Example:
        >>> from ngp_kornia.nets.upright_lines import UprightLinesNet
        >>> flat = torch.full((1, 4), -1.3862943611198906)
        >>> fused = fuse_line_reading(UprightLinesNet(4, 1), torch.tensor([[0.5, 0.1, 0.1, 0.1, 0.2]]), flat)
        >>> [round(p, 4) for p in fused[0].tolist()]
        [0.5, 0.1, 0.1, 0.1, 0.2]
    """
    structured = probs[:, :4].sum(-1, keepdim=True)
    with torch.no_grad():
        fused = net.fuse(probs[:, :4], lines).to(probs) * structured
    return torch.cat([fused, probs[:, 4:]], -1)


def read_beside(net: nn.Module, images: Tensor, prior: float) -> Callable[[], Tensor]:
    """Start :func:`upright_probabilities` on a second thread where the call may use two cores, and return the
    function that gives its result (computed there, or here if that thread has not started on it). The same
    computation either way: torch releases the GIL, so the reading costs no time beside the frame search."""
    if strip_threads(2) < 2:
        return lambda: upright_probabilities(net, images, prior)
    return beside(upright_probabilities, net, images, prior)


#: the largest pitch the parser answers for a photo turned by a quarter turn: its "vertical" is then a horizontal
#: vanishing point, the one nearer the image's vertical, at most 45 degrees from the view direction
_TURNED_PITCH = 45.0


def weigh_by_pitch(probs: Tensor, pitch: Tensor, spread: float) -> Tensor:
    """(B, 5) probabilities with the answered ``pitch`` (B,) in degrees as a further cue between the four turns.

    Photos are taken with the camera held near level: read as upright or turned by 180 degrees (which keeps the
    pitch's size), an answer's pitch is likely within ``spread`` degrees of level (half-normal). A photo turned by
    90 or 270 degrees is answered with a horizontal vanishing point taken for the vertical one, so its pitch lies
    anywhere up to 45 degrees (uniform). The turns are weighed by these likelihoods and rescaled to their former
    total, so the structure-free reading, and with it ``valid``, stays as it was.

    Example:
        >>> probs = torch.tensor([[0.4, 0.4, 0.0, 0.0, 0.2]])
        >>> steep = weigh_by_pitch(probs, torch.tensor([30.0]), spread=15.0)[0]
        >>> bool(steep[1] > steep[0]), round(float(steep[4]), 2)
        (True, 0.2)
    """
    size = pitch.to(probs.dtype).abs()
    level = torch.exp(-0.5 * (size / spread) ** 2) * (2.0 / (spread * (2.0 * torch.pi) ** 0.5))
    turned = torch.where(size <= _TURNED_PITCH, 1.0 / _TURNED_PITCH, 1e-3 / _TURNED_PITCH).to(probs.dtype)
    likelihood = torch.stack([level, turned, level, turned], -1)
    turns = probs[:, :4] * likelihood
    total, before = turns.sum(-1, keepdim=True), probs[:, :4].sum(-1, keepdim=True)
    turns = torch.where(total > 0, turns * before / total.clamp_min(torch.finfo(probs.dtype).tiny), probs[:, :4])
    return torch.cat([turns, probs[:, 4:]], -1)


def turned_answer(result: Calibration, turns: Tensor, use: Tensor) -> Calibration:
    """The answer, where ``use`` (B,), for the image turned counter-clockwise by ``turns`` (B,) quarter turns from
    upright: the frame's axis (either sign) whose direction in the image is nearest the one that turn gives the
    scene's up (left for one quarter turn, down for two, right for three) becomes up; the frame, the focal length
    and the principal point stay, and pitch, roll, yaw, up, zenith, horizon and VPs follow. Every other field
    (score, confidence, standard deviations, distortion) is kept as it is.

    Example:
        >>> from ngp_kornia.pipeline.answer import calibration_from_camera
        >>> K = torch.tensor([[[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]])
        >>> level = calibration_from_camera(K, torch.eye(3)[None], torch.ones(1), torch.ones(1, dtype=torch.bool),
        ...                                 480, 640)
        >>> round(float(turned_answer(level, torch.tensor([1]), torch.tensor([True])).roll), 1)
        -90.0
    """
    if not bool(use.any()):
        return result
    R = result.R
    angle = turns.to(R.dtype) * (torch.pi / 2)
    want = torch.stack([-torch.sin(angle), -torch.cos(angle)], -1)  # the image direction of up, turned
    axes = torch.cat([R, -R], -1).transpose(-1, -2)  # (B, 6, 3): each axis, either sign, as an up candidate
    flat = axes[..., :2] / torch.linalg.vector_norm(axes[..., :2], dim=-1, keepdim=True).clamp_min(1e-12)
    pick = (flat * want[:, None]).sum(-1).argmax(-1)
    rows = torch.arange(len(R), device=R.device)
    up = axes[rows, pick]
    others = axes[rows[:, None], (pick[:, None] % 3 + torch.arange(1, 3, device=R.device)) % 3]  # (B, 2, 3)
    frame = canonical_manhattan_rotation(torch.stack([others[:, 0], -up, others[:, 1]], -1))
    R = torch.where(use[:, None, None], frame, result.R)
    return replace(result, camera=result.camera.replace(R=R))


def apply_upright(
    result: Calibration,
    probs: Tensor,
    sure: float = 0.9,
    turn_back: bool = False,
    fallback_fov: float = 60.0,
    doubt: float = 0.0,
    doubt_power: float = 1.0,
) -> Calibration:
    """The answer with ``upright`` and ``turned`` filled in and its confidence lowered where the check doubts the
    orientation it answers for.

    ``upright`` is the probability that the image is upright and shows structure (the network's, calibrated on real
    photos held back from its training and weighed by the prior). ``turned`` is the image's counter-clockwise turn
    from upright in degrees (90, 180 or 270) where one turn's probability is at least ``sure``, else 0: a turn is
    reported only where the check is sure of it. Where ``upright`` is below ``doubt`` the confidence is multiplied
    by ``(upright / doubt) ** doubt_power`` (down to 0 as the doubt grows, continuous at the level); at or above it,
    it is the lines' own: the network reads real photos far from perfectly, and multiplying every confidence by its
    reading would reorder the upright photos' answers by its noise. With ``turn_back``, where a turn is reported the
    answer is that of the turned camera (:func:`turned_answer`; its roll then lies beyond 45 degrees, which no
    upright answer has) and its confidence is multiplied by that turn's probability instead; not where a gravity
    prior says which way is up. ``valid`` becomes False where no structure is likelier than every reading with
    structure: the answer then rests on no line evidence worth the name, so it is that of an image without a frame
    (:func:`~ngp_kornia.pipeline.answer.level_answer`: a level camera with the known focal length or
    ``fallback_fov`` degrees on the long side), with confidence 0 and the standard deviations of an answer without a
    frame (90 degrees for pitch and roll, 180 for the field of view, 0 for a known focal length).
    """
    probs = probs.to(result.focal.dtype)
    upright = probs[:, 0]
    structured = probs[:, :4]
    turns = structured.argmax(-1)
    valid = result.valid & (probs[:, 4] < structured.max(-1).values)
    likeliest = structured.gather(-1, turns[:, None])[:, 0]
    reported = (turns > 0) & (likeliest >= sure) & valid
    back = reported & turn_back & (result.gravity is None)
    doubted = (upright / doubt).clamp(max=1.0) ** doubt_power if doubt > 0 else torch.ones_like(upright)
    factor = torch.where(back, likeliest, doubted)
    result = level_answer(turned_answer(result, turns, back), result.valid & ~valid, fallback_fov)
    confidence = None if result.confidence is None else torch.where(valid, result.confidence * factor, 0.0)
    stds = {}
    for name, nothing in (("pitch_std", 90.0), ("roll_std", 90.0), ("fov_v_std", 180.0)):
        std = getattr(result, name)
        if std is not None:  # a known focal length keeps its 0
            stds[name] = torch.where(valid | (std == 0), std, nothing)
    turned = torch.where(reported, turns * 90, 0).long()
    return replace(result, valid=valid, confidence=confidence, upright=upright, turned=turned, **stds)
