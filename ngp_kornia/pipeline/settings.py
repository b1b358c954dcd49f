"""The parser's settings, one small dataclass per stage, and :class:`ParserConfig`, which holds one of each.

Settings say how the pipeline works and are the same for every image a parser sees; what differs per call (the
sampling seed, what is known of the camera, the thread policy) are arguments of the call
(:meth:`~ngp_kornia.pipeline.parser.NeuralGeometricParser.forward`, :func:`ngp_kornia.calibrate`).

Every field states its type and range once, in its metadata; :func:`check_settings` checks them on construction (and
on ``dataclasses.replace``), and the command line builds its options from the same fields
(:func:`setting_fields`). This module imports nothing heavy, so ``ngp --help`` can read it before torch loads.

Example:
    >>> cfg = ParserConfig(segments=SegmentSettings(working_size=640))
    >>> cfg.segments.working_size, cfg.horizon.refine
    (640, True)
    >>> SamplingSettings(num_frames=0)
    Traceback (most recent call last):
    ...
    ngp_kornia.errors.ConfigError: SamplingSettings.num_frames must be an integer in [1, 65536], got 0
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
from collections.abc import Iterator
from dataclasses import dataclass, field

from ngp_kornia.errors import ConfigError, shown
from ngp_kornia.suggest import did_you_mean, either

__all__ = [
    "DETECTORS",
    "DistortionSettings",
    "EvidenceSettings",
    "HorizonSettings",
    "ParserConfig",
    "PolishSettings",
    "SamplingSettings",
    "ScoringSettings",
    "SegmentSettings",
    "SharedSettings",
    "TrustSettings",
    "UprightSettings",
    "check_settings",
    "locate_setting",
    "setting_fields",
]

#: the line detectors :class:`SegmentSettings` accepts
DETECTORS = ("lsd", "fld")


def _number(default, low, high, *, open_low=False, open_high=False):
    """A numeric field and its range, closed unless ``open_low`` / ``open_high``."""
    return field(default=default, metadata={"range": (low, high, open_low, open_high)})


def _choice(default, choices):
    return field(default=default, metadata={"choices": choices})


def _flag(default: bool):
    return field(default=default, metadata={"flag": True})


def _numbers(default: tuple, count: int | None, low: float, meaning: str):
    """A tuple of positive numbers (``count`` of them, or at least one)."""
    return field(default=default, metadata={"tuple": (count, low), "meaning": meaning})


@dataclass(frozen=True)
class SegmentSettings:
    """Line detection (:mod:`ngp_kornia.pipeline.segments`).

    Attributes:
        working_size: LSD runs on the image resized to this long side, in pixels; smaller images at their own size.
            1280 keeps the detail of most photos' lines; 640 is faster on large images.
        min_length: shorter segments (working-resolution pixels) are dropped.
        max_segments: at most this many segments per image, the longest kept.
        detector: ``"lsd"`` (the most accurate) or ``"fld"`` (OpenCV's FastLineDetector, faster, less accurate).
        line_strips: LSD runs on this many horizontal strips at once (OpenCV releases the GIL) and joins the pieces
            of lines cut between them; the segments depend on this number only, not on how many threads run them.
    """

    working_size: int = _number(1280, 32, 16384)
    min_length: float = _number(10.0, 0.0, 1e6)
    max_segments: int = _number(512, 1, 16384)
    detector: str = _choice("lsd", DETECTORS)
    line_strips: int = _number(2, 1, 16)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class EvidenceSettings:
    """The line-evidence stage (:mod:`ngp_kornia.pipeline.evidence`), between line detection and candidate sampling.

    Attributes:
        enabled: drop the segments the learned line evidence says lie on no man-made structure (where the parser has
            the network: every weight set of :func:`ngp_kornia.calibrate` has it). Off here, on in the ``"default"``
            weight set (:data:`ngp_kornia.api.DEFAULT_SETTINGS`): with ZSNet and FSNet it beats the geometric path
            on the real sets, most on real indoor scenes (BENCHMARKS.md).
        keep: the least structure weight of a segment kept (the network's weights are set so that 0.1 keeps 97% of
            the structural segments of renders).
        weigh: the kept segments' structure weights also multiply their lengths in the candidates' sampling, the
            Manhattan score and the horizon search.
    """

    enabled: bool = _flag(False)
    keep: float = _number(0.1, 0.0, 1.0)
    weigh: bool = _flag(False)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class UprightSettings:
    """The orientation and structure check (:mod:`ngp_kornia.pipeline.upright_check`).

    Attributes:
        enabled: report ``upright`` and ``turned`` and lower the confidence where the check doubts the photo.
        prior: the share of photos with structure handed over upright (the readings, calibrated for the four turns
            equally often, are weighed by it: an unsure reading leans to upright, as most photos are).
        sure: the probability one turn needs to be reported (``turned``; below it 0).
        doubt: the upright probability below which the confidence is multiplied by ``(upright / doubt) **
            doubt_power``, ``ngp calibrate`` warns and ``ngp rectify`` refuses the photo.
        doubt_power: how steeply a doubted photo's confidence falls (2: ``upright`` itself at half the level).
        pitch_spread: how far from level, in degrees, photos are taken: the answered pitch as a further cue (a photo
            turned a quarter is answered with a steep pitch; 0: not used).
        lines: fuse the turn read from the detected segments (where the parser has an ``UprightLinesNet``).
        turn_back: where a turn is reported, answer the turned photo's camera (roll beyond 45 degrees) at the
            confidence times that turn's probability (:func:`ngp_kornia.pipeline.upright_check.turned_answer`).
    """

    enabled: bool = _flag(True)
    prior: float = _number(0.75, 0.01, 0.99)
    sure: float = _number(0.9, 0.0, 1.0)
    doubt: float = _number(0.5, 0.0, 1.0)
    doubt_power: float = _number(2.0, 1.0, 8.0)
    pitch_spread: float = _number(15.0, 0.0, 90.0)
    turn_back: bool = _flag(True)
    lines: bool = _flag(True)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class SamplingSettings:
    """Zenith, horizontal-VP and Manhattan-frame candidates (:mod:`ngp_kornia.pipeline.candidates`).

    Attributes:
        num_zenith_lines: near-vertical lines the zenith network reads (the paper's |L_z|, Eq. 3).
        num_zenith: zenith candidates drawn from pairs of near-vertical lines (|Z|, Eq. 4).
        vertical_threshold: lines steeper than this many degrees count as near-vertical (delta_z, Eq. 4).
        zenith_threshold: the zenith network's score a candidate needs to count (delta_c, Eq. 12).
        vertical_tol: a segment within this angle (degrees) of the ray to the zenith estimate counts as vertical in
            the junction filter.
        junction_radius: endpoint distance for a junction, in units of half the image's long side.
        num_horizontal: horizontal VP candidates (half per group).
        num_frames: Manhattan-frame candidates from a zenith and a horizontal VP (the paper's) per image.
        num_horizontal_frames: further candidates from two horizontal VPs, which fix the focal length of a level
            camera (zenith at infinity); 0 disables them.
        focal_range: allowed focal lengths (low, high), in units of half the image's long side.
    """

    num_zenith_lines: int = _number(256, 1, 16384)
    num_zenith: int = _number(256, 1, 16384)
    vertical_threshold: float = _number(67.5, 0.0, 90.0, open_low=True, open_high=True)
    zenith_threshold: float = _number(0.5, 0.0, 1.0, open_high=True)
    vertical_tol: float = _number(5.0, 0.0, 90.0, open_high=True)
    junction_radius: float = _number(0.03, 0.0, 10.0)
    num_horizontal: int = _number(256, 2, 16384)
    num_frames: int = _number(1024, 1, 65536)
    num_horizontal_frames: int = _number(512, 0, 65536)
    focal_range: tuple[float, float] = _numbers((0.8, 4.0), 2, 0.0, "two numbers 0 < low < high (half image sides)")

    def __post_init__(self) -> None:
        check_settings(self)
        if not self.focal_range[0] < self.focal_range[1]:
            low, high = self.focal_range
            raise ConfigError(f"SamplingSettings.focal_range must be (low, high) with low < high, got {low, high}")


@dataclass(frozen=True)
class ScoringSettings:
    """Frame scores and the top-k answer (Eq. 21-23).

    Attributes:
        kernel_angle: width of the sharp closeness kernel of the Manhattan score, degrees.
        top_k: the answer averages this many best frames (k, Eq. 23).
        num_scored: frames FSNet scores per image, the best by Manhattan score (unused without FSNet).
        use_manhattan: a frame's score is FSNet's times its Manhattan score (``s_vh * m_i``, Eq. 22), else FSNet's.
        fallback_fov: long-side field of view (degrees) reported when an image has no valid frame.
    """

    kernel_angle: float = _number(89.0, 0.0, 90.0, open_low=True, open_high=True)
    top_k: int = _number(8, 1, 1024)
    num_scored: int = _number(16, 1, 1024)
    use_manhattan: bool = _flag(True)
    fallback_fov: float = _number(60.0, 0.0, 180.0, open_low=True, open_high=True)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class HorizonSettings:
    """The horizon search after the frame search (:mod:`ngp_kornia.pipeline.horizon`).

    Attributes:
        refine: move the horizon (and focal length) to the one the segments support best; the search runs either
            way, because the confidence reads its line support.
        pitch_range: the coarse hypotheses span the frame's pitch +- this, degrees.
        pitch_step: coarse step, degrees.
        fine_step: step of the fine grid around the best coarse hypothesis, degrees.
        num_peaks: horizontal VPs found along each horizon.
        kernel_deg: width of the search's closeness kernel, degrees.
        zenith_tol: inlier angle of the zenith refinement, degrees.
        margin: a hypothesis must beat the frame's own line support by this fraction to replace it.
        tie_zenith: score each hypothesis' vertical segments against its own zenith, so pitch moves zenith and
            horizon together.
        focal_scales: the hypotheses are repeated with the frame's focal length times each of these (1 is always
            tried first); ignored when the focal length is known.
        frame_roll: also search the pitch grid at the frame's roll (about 1.5x the time).
    """

    refine: bool = _flag(True)
    pitch_range: float = _number(8.0, 0.0, 45.0)
    pitch_step: float = _number(1.0, 0.01, 45.0)
    fine_step: float = _number(0.25, 0.01, 45.0)
    num_peaks: int = _number(4, 1, 64)
    kernel_deg: float = _number(1.0, 0.0, 45.0, open_low=True)
    zenith_tol: float = _number(2.0, 0.0, 45.0, open_low=True)
    margin: float = _number(0.08, 0.0, 10.0)
    tie_zenith: bool = _flag(True)
    focal_scales: tuple[float, ...] = _numbers((0.8, 0.9, 1.1, 1.25), None, 0.0, "positive numbers")
    frame_roll: bool = _flag(False)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class PolishSettings:
    """Refitting the frame on the segments that point at its three VPs (:mod:`ngp_kornia.pipeline.polish`).

    Attributes:
        enabled: polish the frame before the horizon search, where that raises its line support (opt-in: more
            accurate on renders, a confidence that ranks real photos less well).
        scales: focal scales tried (only the rotation is refitted when the focal length is known).
    """

    enabled: bool = _flag(False)
    scales: tuple[float, ...] = _numbers(
        (0.88, 0.91, 0.94, 0.97, 1.0, 1.03, 1.06, 1.09, 1.12), None, 0.0, "positive numbers"
    )

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class TrustSettings:
    """The trust fields, confidence and standard deviations (:mod:`ngp_kornia.pipeline.trust`).

    Attributes:
        centre_std: how far the principal point (the camera's centre) may be from the image centre, a standard
            deviation per axis as a fraction of the image height. The parser assumes the centre; this widens
            ``pitch_std``, ``roll_std`` and ``fov_v_std`` by the error such an offset causes (answers and
            ``confidence`` do not change). 0.025, the offset of the one calibrated real camera of the development
            photos, suits unknown cameras; 0 says it is known to be at the centre.
    """

    centre_std: float = _number(0.025, 0.0, 0.25)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class SharedSettings:
    """One camera across many photos, ``calibrate(photos, priors={"shared_intrinsics": True})``
    (:mod:`ngp_kornia.pipeline.shared_camera`).

    Attributes:
        focal_step: relative step of the common grid of focal lengths every photo's frame is scored at.
        window: each photo is scored at the focal lengths within this fraction of its own answer.
        kernel_deg: width of the closeness kernel of each photo's line support, degrees.
        inlier_deg: inlier angle of the rotation refitted at each focal length, degrees.
        iterations: Gauss-Newton steps of that refit.
        bootstrap: resamples of the photos behind the shared focal length's standard deviation.
    """

    focal_step: float = _number(0.01, 0.001, 0.2)
    window: float = _number(0.3, 0.0, 10.0, open_low=True)
    kernel_deg: float = _number(1.0, 0.0, 45.0, open_low=True)
    inlier_deg: float = _number(1.5, 0.0, 45.0, open_low=True)
    iterations: int = _number(3, 1, 20)
    bootstrap: int = _number(200, 0, 10000)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class DistortionSettings:
    """Radial distortion from the curvature of chained segments, the distortion prior ``"estimate"``
    (:mod:`ngp_kornia.pipeline.distortion`); the coefficients here are in units of half the image's long side.

    Attributes:
        gap: two segments chain when an endpoint of one is this close to an endpoint of the other (units of half
            the long side).
        angle_deg: and their directions differ by less than this, degrees.
        max_pairs: at most this many chained pairs per image, the longest.
        min_pairs: fewer pairs keep a distortion-free camera (no evidence).
        min_gain: so does a best coefficient whose cost is not below the distortion-free one's by this fraction of
            the cost of the pairs that are straight at either; the calibrations with and without it decide the rest.
        tolerance_deg: a pair whose pieces' endpoints are off the other piece's line by more than this angle (root
            mean square, degrees) counts as two lines that met by chance.
        search_low: the least coefficient searched (barrel distortion is negative).
        search_high: the largest coefficient searched.
        step: the search's step.
    """

    gap: float = _number(0.05, 0.0, 1.0, open_low=True)
    angle_deg: float = _number(15.0, 0.0, 45.0, open_low=True)
    max_pairs: int = _number(1000, 1, 100000)
    min_pairs: int = _number(8, 1, 100000)
    min_gain: float = _number(0.05, 0.0, 1.0)
    tolerance_deg: float = _number(1.0, 0.0, 45.0, open_low=True)
    search_low: float = _number(-0.6, -2.0, 0.0)
    search_high: float = _number(0.3, 0.0, 2.0)
    step: float = _number(0.005, 0.0001, 0.5)

    def __post_init__(self) -> None:
        check_settings(self)


#: the stages of :class:`ParserConfig`, in pipeline order
_STAGES = {
    "segments": SegmentSettings,
    "evidence": EvidenceSettings,
    "sampling": SamplingSettings,
    "scoring": ScoringSettings,
    "polish": PolishSettings,
    "horizon": HorizonSettings,
    "trust": TrustSettings,
    "shared": SharedSettings,
    "distortion": DistortionSettings,
    "upright": UprightSettings,
}


@dataclass(frozen=True)
class ParserConfig:
    """The settings of every stage of the parser; the defaults are the paper's where it gives them.

    Attributes:
        segments: line detection (:class:`SegmentSettings`).
        evidence: the learned line evidence (:class:`EvidenceSettings`).
        sampling: candidate sampling (:class:`SamplingSettings`).
        scoring: frame scores and the top-k answer (:class:`ScoringSettings`).
        polish: the optional frame refit (:class:`PolishSettings`).
        horizon: the horizon search (:class:`HorizonSettings`).
        trust: confidence and standard deviations (:class:`TrustSettings`).
        shared: one camera across many photos (:class:`SharedSettings`).
        distortion: radial distortion from the segments' curvature (:class:`DistortionSettings`).
        upright: the orientation and structure check (:class:`UprightSettings`).
    """

    segments: SegmentSettings = field(default_factory=SegmentSettings)
    evidence: EvidenceSettings = field(default_factory=EvidenceSettings)
    sampling: SamplingSettings = field(default_factory=SamplingSettings)
    scoring: ScoringSettings = field(default_factory=ScoringSettings)
    polish: PolishSettings = field(default_factory=PolishSettings)
    horizon: HorizonSettings = field(default_factory=HorizonSettings)
    trust: TrustSettings = field(default_factory=TrustSettings)
    shared: SharedSettings = field(default_factory=SharedSettings)
    distortion: DistortionSettings = field(default_factory=DistortionSettings)
    upright: UprightSettings = field(default_factory=UprightSettings)

    def __post_init__(self) -> None:
        for name, kind in _STAGES.items():
            value = getattr(self, name)
            if not isinstance(value, kind):
                raise ConfigError(f"ParserConfig.{name} must be a {kind.__name__}, got {type(value).__name__}")

    def replace(self, **changes: object) -> ParserConfig:
        """A copy with settings changed, by ``stage.field`` or by a field name unique among the stages.

        Example:
            >>> ParserConfig().replace(**{"horizon.refine": False, "working_size": 640}).segments.working_size
            640
        """
        stages: dict[str, dict] = {}
        for key, value in changes.items():
            stage, name = locate_setting(key)
            stages.setdefault(stage, {})[name] = value
        return dataclasses.replace(
            self, **{s: dataclasses.replace(getattr(self, s), **kw) for s, kw in stages.items()}
        )


def setting_fields() -> Iterator[tuple[str, dataclasses.Field, str]]:
    """Every setting of :class:`ParserConfig`: (stage name, field, its help text from the stage's docstring)."""
    for stage, kind in _STAGES.items():
        docs = _attribute_docs(kind.__doc__ or "")
        for f in dataclasses.fields(kind):
            yield stage, f, docs.get(f.name, "")


def locate_setting(key: str) -> tuple[str, str]:
    """``(stage, field)`` of a setting named ``stage.field`` or by a field name that only one stage has.

    Raises:
        ConfigError: no such setting, or a field name of several stages; the message names the settings meant.
    """
    if "." in key:
        stage, name = key.split(".", 1)
        kind = _STAGES.get(stage)
        if kind is not None and name in {f.name for f in dataclasses.fields(kind)}:
            return stage, name
    else:
        found = [f"{s}.{f.name}" for s, f, _ in setting_fields() if f.name == key]
        if len(found) == 1:
            return tuple(found[0].split("."))
        if found:
            raise ConfigError(f"setting {key!r} is ambiguous: did you mean {either(found)}?")
    hint = did_you_mean(key, [f"{s}.{f.name}" for s, f, _ in setting_fields()])
    raise ConfigError(f"unknown setting {key!r}; {hint}settings are stage.field with stage one of "
                      f"{', '.join(_STAGES)} (e.g. horizon.refine, segments.working_size)")


def _attribute_docs(doc: str) -> dict[str, str]:
    """The ``Attributes:`` entries of a Google docstring, one line each."""
    part = doc.split("Attributes:", 1)[-1]
    entries = re.findall(r"^\s{8}(\w+): (.*?)(?=^\s{8}\w+: |\Z)", part, flags=re.M | re.S)
    return {name: " ".join(text.split()) for name, text in entries}


def check_settings(settings: object) -> None:
    """Check every field of a stage's settings against its metadata; numpy numbers are taken as Python ones.

    Raises:
        ConfigError: a field of the wrong type, NaN, or out of range; the message names the field and the range.
    """
    owner = type(settings).__name__
    for f in dataclasses.fields(settings):
        value = getattr(settings, f.name)
        checked = _checked(f, value, f"{owner}.{f.name}")
        if checked is not value:
            object.__setattr__(settings, f.name, checked)  # frozen: set once, on construction


def _checked(f: dataclasses.Field, value: object, name: str) -> object:
    meta = f.metadata
    if "flag" in meta:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} must be True or False, got {shown(value)}")
        return value
    if "choices" in meta:
        if not isinstance(value, str) or value not in meta["choices"]:
            raise ConfigError(f"{name} must be one of {', '.join(meta['choices'])}, got {shown(value)}")
        return value
    if "tuple" in meta:
        return _checked_tuple(value, name, *meta["tuple"], meta["meaning"])
    return _checked_number(value, name, f.type in ("int", int), meta["range"])


def _checked_number(value: object, name: str, integer: bool, bounds: tuple) -> int | float:
    low, high, open_low, open_high = bounds
    meaning = f"in {'(' if open_low else '['}{low:g}, {high:g}{')' if open_high else ']'}"
    if integer:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ConfigError(f"{name} must be an integer {meaning}, got {shown(value)}")
        value = int(value)
    else:
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number {meaning}, got {shown(value)}")
        value = float(value)
    below = value <= low if open_low else value < low
    above = value >= high if open_high else value > high
    if below or above:
        raise ConfigError(f"{name} must be {'an integer' if integer else 'a number'} {meaning}, got {shown(value)}")
    return value


def _checked_tuple(value: object, name: str, count: int | None, low: float, meaning: str) -> tuple[float, ...]:
    ok = isinstance(value, (tuple, list)) and (len(value) == count if count else len(value) >= 1)
    ok = ok and all(
        isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > low for v in value
    )
    if not ok:
        raise ConfigError(f"{name} must be {meaning}, got {shown(value)}")
    return tuple(float(v) for v in value)
